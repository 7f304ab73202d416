//! `firmware_sim`: the robot's 16 simulated ODrive axes as their own process on a SocketCAN
//! interface, so the controller can run against them exactly as against real motors.
//!
//! ```text
//! sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0
//! firmware_sim --can vcan0 --log traffic.log
//! ```

use clap::Parser;
use std::process::ExitCode;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::WHEELLEG;

/// Simulated ODrive axes for the wheel-legged robot on a SocketCAN bus.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// SocketCAN interface to attach to (for example vcan0).
    #[arg(long)]
    can: String,
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
    /// Initial body clearance the legs are at (metres).
    #[arg(long, default_value_t = WHEELLEG.default_clearance_m)]
    clearance_m: f32,
    /// Initial wheel track the legs are at (metres).
    #[arg(long, default_value_t = WHEELLEG.default_track_m)]
    track_m: f32,
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

#[cfg(not(all(feature = "socketcan", target_os = "linux")))]
fn run(args: &Args) -> Result<(), Box<dyn std::error::Error>> {
    Err(format!(
        "cannot attach to {}: built without SocketCAN (Linux and the `socketcan` feature needed)",
        args.can
    )
    .into())
}

#[cfg(all(feature = "socketcan", target_os = "linux"))]
fn run(args: &Args) -> Result<(), Box<dyn std::error::Error>> {
    use std::io::BufWriter;
    use std::time::{Duration, Instant};
    use wheelleg_firmware_sim::bus::Transport;
    use wheelleg_firmware_sim::candump::{CandumpWriter, DEFAULT_EPOCH_US};
    use wheelleg_firmware_sim::firmware::Firmware;
    use wheelleg_firmware_sim::socketcan::SocketCan;
    use wheelleg_runtime::can::protocol::NodeId;
    use wheelleg_runtime::can::NodeMap;

    if !(args.rate_hz.is_finite() && args.rate_hz > 0.0 && args.rate_hz <= 100_000.0) {
        return Err("--rate-hz must be in (0, 100000]".into());
    }
    let start = LegConfig {
        clearance_m: args.clearance_m,
        track_m: args.track_m,
    };
    let mut firmware = Firmware::for_robot(&WHEELLEG, &NodeMap::NOMINAL, start)
        .map_err(|e| format!("start pose {start:?} unreachable: {e:?}"))?;
    if let Some(n) = args.silent_node {
        let node = NodeId::new(n).ok_or("--silent-node must be 0..=63")?;
        firmware
            .node_mut(node)
            .ok_or("--silent-node is not on the node map")?
            .set_silent(true);
    }
    let socket = SocketCan::open(&args.can).map_err(|e| {
        format!(
            "cannot open {}: {e} (does the interface exist and is it up?)",
            args.can
        )
    })?;
    // Log what this process sees and says, by wrapping the socket.
    struct Logged<T> {
        inner: T,
        log: Option<CandumpWriter<BufWriter<std::fs::File>>>,
    }
    impl<T: Transport> Transport for Logged<T> {
        fn send(
            &mut self,
            frame: &wheelleg_runtime::can::CanFrame,
            now_us: u64,
        ) -> Result<(), wheelleg_firmware_sim::bus::BusError> {
            if let Some(log) = &mut self.log {
                log.log(now_us, frame)?;
            }
            self.inner.send(frame, now_us)
        }
        fn recv(
            &mut self,
            now_us: u64,
        ) -> Result<Option<wheelleg_runtime::can::CanFrame>, wheelleg_firmware_sim::bus::BusError>
        {
            let frame = self.inner.recv(now_us)?;
            if let (Some(log), Some(f)) = (&mut self.log, &frame) {
                log.log(now_us, f)?;
            }
            Ok(frame)
        }
    }
    let epoch_us = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(DEFAULT_EPOCH_US, |d| d.as_micros() as u64);
    let log = match &args.log {
        Some(path) => Some(CandumpWriter::new(
            BufWriter::new(std::fs::File::create(path)?),
            &args.can,
            epoch_us,
        )),
        None => None,
    };
    let mut bus = Logged { inner: socket, log };
    let period = Duration::from_secs_f64(1.0 / args.rate_hz);
    let t0 = Instant::now();
    let mut next = t0;
    eprintln!(
        "firmware_sim: {} axes on {} at {} Hz",
        firmware.axes().len(),
        args.can,
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
    let stats = firmware.stats();
    eprintln!(
        "firmware_sim: received {} frames ({} malformed, {} for other nodes)",
        stats.received, stats.malformed, stats.foreign
    );
    Ok(())
}
