//! `firmware_sim`: a robot's 16 simulated ODrive axes as their own process on a SocketCAN
//! interface or behind an SLCAN endpoint, so the controller or any CAN tool can run against
//! them exactly as against real motors. The axes are the robot description's (`--robot`,
//! the shipped robot by default): its node ids, directions and gear ratios. Like ODrives out of
//! the box, they have no watchdog unless `--watchdog-ms` sets one; they run firmware 0.5.x,
//! which has no Get_Version, unless `--firmware-version` gives a version to answer it with.
//!
//! ```text
//! sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0
//! firmware_sim --can vcan0 --log traffic.log
//! firmware_sim --slcan tcp:127.0.0.1:20108     # python-can: socket://127.0.0.1:20108
//! firmware_sim --slcan pty                     # prints the /dev/pts/N to open
//! firmware_sim --robot robots/strider.toml --slcan tcp:127.0.0.1:0
//! firmware_sim --can vcan0 --watchdog-ms 100   # as the closed loop configures its axes
//! ```

use clap::{ArgGroup, Parser};
use std::io::{BufWriter, Write};
use std::process::ExitCode;
use std::time::{Duration, Instant};
use wheelleg_firmware_sim::bus::{BusError, Transport};
use wheelleg_firmware_sim::candump::{CandumpWriter, DEFAULT_EPOCH_US};
use wheelleg_firmware_sim::firmware::Firmware;
use wheelleg_firmware_sim::slcan::{EndpointSpec, SlcanEndpoint};
use wheelleg_robot::RobotDescription;
use wheelleg_runtime::can::protocol::{NodeId, Version};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::LegConfig;

/// Simulated ODrive axes for the wheel-legged robot on a SocketCAN bus or an SLCAN endpoint.
#[derive(Parser, Debug)]
#[command(version, about, group(ArgGroup::new("bus").required(true).args(["can", "slcan"])))]
struct Args {
    /// SocketCAN interface to attach to (for example vcan0).
    #[arg(long)]
    can: Option<String>,
    /// SLCAN (Lawicel ASCII) endpoint to serve the axes on, as a USB-CAN adapter would:
    /// tcp:HOST:PORT (port 0 picks a free one) or pty (a pseudo-terminal). The place to
    /// connect to is printed on stdout.
    #[arg(long, value_parser = parse_endpoint)]
    slcan: Option<EndpointSpec>,
    /// Physics rate of the simulated motors.
    #[arg(long, default_value_t = 1000.0)]
    rate_hz: f64,
    /// Stop after this many seconds (runs until killed if absent).
    #[arg(long)]
    duration_s: Option<f64>,
    /// Write the received traffic to this file in `candump -L` format.
    #[arg(long)]
    log: Option<std::path::PathBuf>,
    /// Fault injection: this node id never transmits.
    #[arg(long)]
    silent_node: Option<u8>,
    /// The robot whose axes to simulate (robots/NAME.toml). Default: the shipped robot.
    #[arg(long)]
    robot: Option<std::path::PathBuf>,
    /// Initial body clearance the legs are at (metres). Default: the robot's default pose.
    #[arg(long)]
    clearance_m: Option<f32>,
    /// Initial wheel track the legs are at (metres). Default: the robot's default pose.
    #[arg(long)]
    track_m: Option<f32>,
    /// Axis watchdog: an armed axis that accepts no setpoint for this many milliseconds goes
    /// idle and latches WATCHDOG_TIMER_EXPIRED. Default: off (0), as on an ODrive whose
    /// watchdog is not enabled; the project's own closed loop runs its axes with 100.
    #[arg(long, default_value_t = 0)]
    watchdog_ms: u64,
    /// Firmware version every axis answers Get_Version with, MAJOR.MINOR.REVISION. Without
    /// it the axes run 0.5.x, which has no Get_Version (nor answers it). The project's loops
    /// speak 0.5.x only and refuse any other at start-up.
    #[arg(long, value_parser = parse_firmware_version)]
    firmware_version: Option<Version>,
}

/// `MAJOR.MINOR.REVISION`, each 0 to 255, as the firmware part of the default version.
fn parse_firmware_version(s: &str) -> Result<Version, String> {
    let parts: Vec<&str> = s.split('.').collect();
    let [major, minor, revision] = parts[..] else {
        return Err(format!(
            "{s:?} is not MAJOR.MINOR.REVISION (for example 0.5.6)"
        ));
    };
    let number = |part: &str, what: &str| {
        part.parse::<u8>()
            .map_err(|_| format!("{s:?}: the {what} {part:?} is not a number from 0 to 255"))
    };
    Ok(Version {
        fw_version_major: number(major, "major version")?,
        fw_version_minor: number(minor, "minor version")?,
        fw_version_revision: number(revision, "revision")?,
        ..Version::ODRIVE_0_5_6
    })
}

fn parse_endpoint(s: &str) -> Result<EndpointSpec, String> {
    s.parse()
        .map_err(|e: wheelleg_firmware_sim::slcan::SpecError| e.to_string())
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("firmware_sim: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: &Args) -> Result<(), Box<dyn std::error::Error>> {
    if !(args.rate_hz.is_finite() && args.rate_hz > 0.0 && args.rate_hz <= 100_000.0) {
        return Err("--rate-hz must be in (0, 100000]".into());
    }
    let description = match &args.robot {
        Some(path) => RobotDescription::load(path)?,
        None => RobotDescription::shipped(),
    };
    let robot = description.robot;
    let start = LegConfig {
        clearance_m: args
            .clearance_m
            .unwrap_or(robot.geometry.default_clearance_m),
        track_m: args.track_m.unwrap_or(robot.geometry.default_track_m),
    };
    let mut firmware = Firmware::for_robot(&robot.geometry, &robot.can, start)
        .map_err(|e| format!("start pose {start:?} unreachable: {e:?}"))?;
    let watchdog_us = args
        .watchdog_ms
        .checked_mul(1_000)
        .ok_or("--watchdog-ms is too large")?;
    firmware.set_watchdog_timeout_us(watchdog_us);
    firmware.set_version(args.firmware_version);
    let version = args.firmware_version.map_or("0.5.x".to_owned(), |v| {
        format!(
            "{}.{}.{}",
            v.fw_version_major, v.fw_version_minor, v.fw_version_revision
        )
    });
    eprintln!(
        "firmware_sim: robot '{}', firmware {version}, watchdog {}, nodes {}",
        description.name,
        match args.watchdog_ms {
            0 => "off".to_owned(),
            ms => format!("{ms} ms"),
        },
        wheelleg_runtime::can::Axis::ALL
            .iter()
            .map(|&axis| robot.can.node_id(axis).get().to_string())
            .collect::<Vec<_>>()
            .join(" ")
    );
    if let Some(n) = args.silent_node {
        let node = NodeId::new(n).ok_or("--silent-node must be 0..=63")?;
        firmware
            .node_mut(node)
            .ok_or("--silent-node is not on the node map")?
            .set_silent(true);
    }
    match (&args.slcan, &args.can) {
        (Some(spec), _) => {
            let mut endpoint = SlcanEndpoint::open(spec)
                .map_err(|e| format!("cannot open the SLCAN endpoint {spec:?}: {e}"))?;
            let place = endpoint.describe();
            // On stdout, flushed, so a script that started this process can read where to
            // connect (port 0 binds a free port; a pty's name is known only once it exists).
            println!("firmware_sim: SLCAN on {place}");
            std::io::stdout().flush()?;
            simulate(&mut firmware, &mut endpoint, "slcan0", &place, args)?;
            let s = endpoint.adapter().stats();
            eprintln!(
                "firmware_sim: SLCAN: {} TCP clients, {} commands, {} malformed and {} refused lines \
                 (answered BEL), {} frames from clients, {} to them, {} dropped (client too slow)",
                s.clients,
                s.commands,
                s.malformed,
                s.refused,
                s.frames_from_client,
                s.frames_to_client,
                s.frames_dropped
            );
        }
        (None, Some(interface)) => run_socketcan(&mut firmware, interface, args)?,
        // clap's argument group requires one of the two.
        (None, None) => return Err("give --can IFACE or --slcan tcp:HOST:PORT|pty".into()),
    }
    let stats = firmware.stats();
    eprintln!(
        "firmware_sim: received {} frames ({} malformed, {} for other nodes)",
        stats.received, stats.malformed, stats.foreign
    );
    Ok(())
}

#[cfg(not(all(feature = "socketcan", target_os = "linux")))]
fn run_socketcan(
    _firmware: &mut Firmware,
    interface: &str,
    _args: &Args,
) -> Result<(), Box<dyn std::error::Error>> {
    Err(format!(
        "cannot attach to {interface}: built without SocketCAN (Linux and the `socketcan` feature \
         needed); --slcan tcp:HOST:PORT works everywhere"
    )
    .into())
}

#[cfg(all(feature = "socketcan", target_os = "linux"))]
fn run_socketcan(
    firmware: &mut Firmware,
    interface: &str,
    args: &Args,
) -> Result<(), Box<dyn std::error::Error>> {
    use wheelleg_firmware_sim::socketcan::SocketCan;
    let mut socket = SocketCan::open(interface).map_err(|e| {
        format!("cannot open {interface}: {e} (does the interface exist and is it up?)")
    })?;
    simulate(firmware, &mut socket, interface, interface, args)
}

/// Logs what this process sees and says, around any transport.
struct Logged<'a, T> {
    inner: &'a mut T,
    log: Option<CandumpWriter<BufWriter<std::fs::File>>>,
}

impl<T: Transport> Transport for Logged<'_, T> {
    fn send(&mut self, frame: &CanFrame, now_us: u64) -> Result<(), BusError> {
        if let Some(log) = &mut self.log {
            log.log(now_us, frame)?;
        }
        self.inner.send(frame, now_us)
    }

    fn recv(&mut self, now_us: u64) -> Result<Option<CanFrame>, BusError> {
        let frame = self.inner.recv(now_us)?;
        if let (Some(log), Some(f)) = (&mut self.log, &frame) {
            log.log(now_us, f)?;
        }
        Ok(frame)
    }
}

/// Steps the axes in real time at `--rate-hz` on `transport` until `--duration-s` (or forever).
/// `log_interface` names the bus in the `candump -L` log, `place` in the start-up line.
fn simulate<T: Transport>(
    firmware: &mut Firmware,
    transport: &mut T,
    log_interface: &str,
    place: &str,
    args: &Args,
) -> Result<(), Box<dyn std::error::Error>> {
    let epoch_us = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(DEFAULT_EPOCH_US, |d| d.as_micros() as u64);
    let log = match &args.log {
        Some(path) => Some(CandumpWriter::new(
            BufWriter::new(std::fs::File::create(path)?),
            log_interface,
            epoch_us,
        )),
        None => None,
    };
    let mut bus = Logged {
        inner: transport,
        log,
    };
    let period = Duration::from_secs_f64(1.0 / args.rate_hz);
    let t0 = Instant::now();
    let mut next = t0;
    eprintln!(
        "firmware_sim: {} axes on {place} at {} Hz",
        firmware.axes().len(),
        args.rate_hz
    );
    loop {
        next += period;
        let now_us = t0.elapsed().as_micros() as u64;
        firmware.run(&mut bus, now_us, period.as_secs_f32())?;
        if args
            .duration_s
            .is_some_and(|d| t0.elapsed().as_secs_f64() >= d)
        {
            break;
        }
        if let Some(wait) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    }
    if let Some(log) = bus.log.take() {
        log.finish()?;
    }
    Ok(())
}
