//! The controller firmware in the loop (`wheelleg demo --controller qemu`): the world on the
//! host, the policy, decision rule, guard, arrival and the 100 Hz motor commands in the
//! firmware's production image in QEMU's mps2-an386, the motors on the host's simulated CAN
//! bus, joined by the two serial links a real robot has:
//!
//! ```text
//! world (Env) --observation link, UART 1 (COBS + CRC-16 + postcard: wire)--> firmware
//!   firmware --decision, step reports--> world
//!   firmware --SLCAN lines, UART 2--> adapter (plant) --> 16 simulated ODrive axes
//!   axes --feedback--> adapter --frame lines--> firmware
//! ```
//!
//! QEMU connects both UARTs to TCP sockets this module listens on. The motors follow the
//! firmware's control periods in lockstep ([`plant`]); the world moves as the in-process closed
//! loop moves it ([`crate::closed_loop`]): after each step the firmware reports its odometry and
//! measured legs, the world checks them against the ideal step with the same tolerances and
//! snaps to the lattice, and a step the world refuses is backed out of by the firmware
//! (`Collided`).

mod episode;
mod faults;
pub mod memory;
pub mod onboard;
pub mod plant;
mod qemu;
#[path = "../../controller/src/wire.rs"]
pub mod wire;

pub use episode::HilEpisode;
pub use faults::{ControllerStop, Faults, LinkFault};
pub use qemu::{default_image, find_or_build_image, image_for, qemu_available, BUILD_COMMAND};

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use nalgebra::Isometry2;
use wheelleg_firmware_sim::rig::StepReport;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::can::host::{AxisSet, BusStats};
use wheelleg_runtime::guard::{CollisionGuard, WindowBounds, DEFAULT_MARGIN_M};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::{target_config, BaseDisplacement};
use wheelleg_runtime::robot::{Robot, WHEELLEG};
use wheelleg_sim::env::{Env, InvalidAction, Observation as SimObservation};
use wheelleg_sim::height_map::MapGrid;

use crate::closed_loop::driver::observation_mm;
use crate::closed_loop::{EpisodeReport, Fault, StepError, Tolerance, Tracking, BITRATE_BPS};
use memory::{RamLayout, RamUse};
use plant::{Plant, PlantClock, PlantFault};
use qemu::qemu_command;
use wire::{FromController, ToController};

/// How long the host waits for any one answer of the firmware (a decision with its guard
/// takes at most some 0.1 s of QEMU's time; the observation timeout's 50 periods of waiting
/// some seconds).
pub const ANSWER_TIMEOUT: Duration = Duration::from_secs(60);

/// A control period's budget on the target part: 10 ms at 170 MHz (an STM32G474-class
/// Cortex-M4F), in cycles.
pub const PERIOD_BUDGET_CYCLES: u64 = 1_700_000;

/// Why the firmware in the loop could not run.
#[derive(Debug)]
pub enum HilError {
    /// `qemu-system-arm` is not installed.
    NoQemu,
    /// The firmware image is missing and could not be built.
    NoImage(PathBuf, String),
    /// A socket, QEMU or the log failed.
    Io(String),
    /// The firmware sent something it should not have, or nothing in time.
    Protocol(String),
}

impl std::fmt::Display for HilError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            HilError::NoQemu => write!(
                f,
                "qemu-system-arm is not installed: run `bash scripts/embedded-toolchain.sh` \
                 (it installs QEMU and the firmware's toolchain)"
            ),
            HilError::NoImage(path, why) => write!(
                f,
                "no firmware image at {} ({why}): build it with `{BUILD_COMMAND}` after \
                 `bash scripts/embedded-toolchain.sh`",
                path.display()
            ),
            HilError::Io(e) => write!(f, "firmware in the loop: {e}"),
            HilError::Protocol(e) => write!(f, "firmware in the loop: {e}"),
        }
    }
}

impl std::error::Error for HilError {}

fn io(context: &str) -> impl Fn(std::io::Error) -> HilError + '_ {
    move |e| HilError::Io(format!("{context}: {e}"))
}

/// The firmware in QEMU with both links open, and the motors behind its CAN adapter.
pub struct Hil {
    qemu: Child,
    obs: TcpStream,
    monitor: TcpStream,
    layout: RamLayout,
    /// The paint file and the RAM QEMU saves (removed with the `Hil`).
    scratch: PathBuf,
    received: Vec<u8>,
    plant: Arc<Mutex<Plant>>,
    can: Option<JoinHandle<Result<(), String>>>,
    window: WindowBounds,
    fine: Vec<f32>,
    sim_observation: SimObservation,
    clock: PlantClock,
}

/// QEMU's instruction clock for `clock`: in lockstep 1 ns per instruction with idle time
/// skipped, so that a period costs only what the firmware executes; on the emulated clock
/// 4 ns per instruction (250 M instructions/s, the power of two nearest above the reference
/// part's 170 MHz at about one cycle per instruction), idle time skipped too: the firmware's
/// periods wait for the host only in the adapter's FIFO, which costs the clock nothing.
fn icount(clock: PlantClock) -> &'static str {
    match clock {
        PlantClock::Lockstep => "shift=0,sleep=off",
        PlantClock::Emulated => "shift=2,sleep=off",
    }
}

/// Instructions per SysTick count (25 MHz) on `clock`'s instruction clock ([`icount`]).
pub fn instructions_per_systick_count(clock: PlantClock) -> u64 {
    match clock {
        PlantClock::Lockstep => memory::INSTRUCTIONS_PER_SYSTICK_COUNT,
        PlantClock::Emulated => memory::INSTRUCTIONS_PER_SYSTICK_COUNT / 4,
    }
}

fn listener() -> Result<(TcpListener, u16), HilError> {
    let listener = TcpListener::bind("127.0.0.1:0").map_err(io("listening for QEMU"))?;
    let port = listener
        .local_addr()
        .map_err(io("listening for QEMU"))?
        .port();
    Ok((listener, port))
}

/// Accepts QEMU's connection, or fails when QEMU exits first.
fn accept(listener: &TcpListener, qemu: &mut Child, what: &str) -> Result<TcpStream, HilError> {
    listener
        .set_nonblocking(true)
        .map_err(io("listening for QEMU"))?;
    let started = Instant::now();
    loop {
        match listener.accept() {
            Ok((stream, _)) => {
                stream.set_nonblocking(false).map_err(io(what))?;
                stream.set_nodelay(true).map_err(io(what))?;
                return Ok(stream);
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if let Ok(Some(status)) = qemu.try_wait() {
                    return Err(HilError::Io(format!(
                        "QEMU exited ({status}) before connecting its {what}"
                    )));
                }
                if started.elapsed() > Duration::from_secs(20) {
                    return Err(HilError::Io(format!("QEMU did not connect its {what}")));
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => return Err(io(what)(e)),
        }
    }
}

impl Hil {
    /// Starts `image` in QEMU with the motors' legs at `start`, the motors' time on `clock`
    /// (an image built for it: [`image_for`]).
    pub fn start(image: &Path, start: LegConfig, clock: PlantClock) -> Result<Hil, HilError> {
        if !qemu_available() {
            return Err(HilError::NoQemu);
        }
        let mut plant = Plant::new(&WHEELLEG, start)
            .map_err(|e| HilError::Io(format!("the start legs have no IK solution: {e:?}")))?;
        plant.set_clock(clock);
        let (obs_listener, obs_port) = listener()?;
        let (can_listener, can_port) = listener()?;
        let (monitor_listener, monitor_port) = listener()?;
        let scratch =
            std::env::temp_dir().join(format!("wheelleg-hil-{}-{obs_port}", std::process::id()));
        std::fs::create_dir_all(&scratch).map_err(io("creating the scratch folder"))?;
        // QEMU runs a copy, so that the layout read here is the image that runs even when the
        // image is rebuilt meanwhile (a long run over many scenes starts QEMU once per scene).
        let copy = scratch.join("image.elf");
        std::fs::copy(image, &copy)
            .map_err(|e| HilError::Io(format!("copying {}: {e}", image.display())))?;
        let image = copy.as_path();
        let layout = RamLayout::of_image(image)?;
        let paint = layout.write_paint(&scratch)?;
        // UART 0 is the console (unused), UART 1 the observation link, UART 2 the CAN
        // adapter; Nagle's algorithm off on both, since QEMU writes a byte per segment and a
        // delayed acknowledgement would hold the next one back. Instructions are counted
        // (1 ns each) and idle time is skipped, so that the firmware's SysTick periods cost
        // only what the firmware executes. The loader paints the free RAM before the core
        // starts, and the monitor saves it at the end ([`Hil::ram_use`]).
        //
        // The firmware's clock runs while it polls for the host's bytes, so a host starved of
        // the CPU looks to it like a dead adapter (its link timeout is 5 periods, some 50 M
        // instructions of polling). QEMU therefore runs at a lower priority than the host
        // (`nice`, where the machine has it): the host's threads preempt it when their bytes
        // are due.
        // On the emulated clock the adapter's bytes reach the firmware through a FIFO it reads
        // by semihosting (docs/controller.md, "The emulated clock"): made here, opened here
        // for reading and writing so that neither end's open waits for the other.
        let fifo = match clock {
            PlantClock::Lockstep => None,
            PlantClock::Emulated => Some(make_fifo(&scratch.join(ADAPTER_FIFO))?),
        };
        let mut qemu = qemu_command()
            .args(["-machine", "mps2-an386", "-display", "none"])
            .args([
                "-monitor",
                &format!("tcp:127.0.0.1:{monitor_port},nodelay=on"),
            ])
            .args(["-serial", "null"])
            .args(["-serial", &format!("tcp:127.0.0.1:{obs_port},nodelay=on")])
            .args(["-serial", &format!("tcp:127.0.0.1:{can_port},nodelay=on")])
            .arg("-device")
            .arg(format!(
                "loader,file={},addr={:#x},force-raw=on",
                paint.display(),
                layout.stack_limit
            ))
            .args(semihosting(clock))
            .args(["-icount", icount(clock), "-kernel"])
            .arg(image)
            .current_dir(&scratch)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::NotFound => HilError::NoQemu,
                _ => io("starting QEMU")(e),
            })?;
        let monitor = accept(&monitor_listener, &mut qemu, "monitor")?;
        let obs = accept(&obs_listener, &mut qemu, "observation link (UART 1)")?;
        let can = accept(&can_listener, &mut qemu, "CAN adapter link (UART 2)")?;
        let plant = Arc::new(Mutex::new(plant));
        let shared = Arc::clone(&plant);
        let can = std::thread::spawn(move || serve_can(can, fifo, shared));
        let window = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M)
            .fine_window(MapGrid::GUARD_FINE.side, MapGrid::GUARD_FINE.cell_m);
        let mut hil = Hil {
            qemu,
            obs,
            monitor,
            layout,
            scratch,
            received: Vec::new(),
            plant,
            can: Some(can),
            window,
            fine: vec![0.0; MapGrid::GUARD_FINE.cells()],
            sim_observation: SimObservation::default(),
            clock,
        };
        // The monitor's greeting ends in its first prompt.
        hil.monitor_prompt()?;
        Ok(hil)
    }

    /// Reads the monitor's output up to its next prompt.
    fn monitor_prompt(&mut self) -> Result<String, HilError> {
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        let mut out = Vec::new();
        let mut buf = [0u8; 1024];
        while !out.ends_with(b"(qemu) ") {
            if Instant::now() > deadline {
                return Err(HilError::Protocol("QEMU's monitor did not answer".into()));
            }
            self.monitor
                .set_read_timeout(Some(Duration::from_secs(1)))
                .map_err(io("QEMU's monitor"))?;
            match self.monitor.read(&mut buf) {
                Ok(0) => return Err(HilError::Protocol("QEMU closed its monitor".into())),
                Ok(n) => out.extend_from_slice(&buf[..n]),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => return Err(io("reading QEMU's monitor")(e)),
            }
        }
        Ok(String::from_utf8_lossy(&out).into_owned())
    }

    /// The firmware's RAM in use so far: its statics, and its stack at the deepest, from the
    /// free RAM painted at the start and saved now by QEMU's monitor.
    pub fn ram_use(&mut self) -> Result<RamUse, HilError> {
        let bytes = self.save_ram(self.layout.stack_limit, self.layout.free_bytes())?;
        Ok(RamUse {
            statics_bytes: self.layout.stack_limit - self.layout.statics_start,
            peak_stack_bytes: self.layout.peak_stack_bytes(&bytes),
        })
    }

    /// The most instructions the firmware spent on one control period's work so far (its waits
    /// for the CAN adapter's bytes left out), read from its RAM by QEMU's monitor: the firmware
    /// keeps the figure in SysTick counts, each 40 instructions under `-icount shift=0`.
    pub fn busiest_period_instructions(&mut self) -> Result<u64, HilError> {
        let bytes = self.save_ram(self.layout.busiest_period_counts, 4)?;
        let counts = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
        Ok(u64::from(counts) * instructions_per_systick_count(self.clock))
    }

    /// `len` bytes of the firmware's RAM from `address`, saved by QEMU's monitor.
    fn save_ram(&mut self, address: u32, len: u32) -> Result<Vec<u8>, HilError> {
        let dump = self.scratch.join("ram.bin");
        let _ = std::fs::remove_file(&dump);
        let command = format!("pmemsave {address:#x} {len} \"{}\"\n", dump.display());
        self.monitor
            .write_all(command.as_bytes())
            .map_err(io("writing to QEMU's monitor"))?;
        let answer = self.monitor_prompt()?;
        let bytes = std::fs::read(&dump).map_err(|e| {
            HilError::Protocol(format!(
                "QEMU's monitor saved no RAM ({e}); it answered: {}",
                answer.trim()
            ))
        })?;
        if bytes.len() != len as usize {
            return Err(HilError::Protocol(format!(
                "QEMU's monitor saved {} bytes of RAM, not {len}",
                bytes.len()
            )));
        }
        Ok(bytes)
    }

    /// The motors and their adapter.
    pub fn plant(&self) -> MutexGuard<'_, Plant> {
        self.plant.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn send(&mut self, message: ToController<'_>, corrupt: bool) -> Result<(), HilError> {
        let envelope = wire::Envelope {
            version: wire::VERSION,
            message,
        };
        let mut payload =
            postcard::to_allocvec(&envelope).map_err(|e| HilError::Protocol(e.to_string()))?;
        let crc = wire::CRC.checksum(&payload);
        payload.extend_from_slice(&crc.to_le_bytes());
        if corrupt {
            // One flipped bit in the payload: the checksum no longer matches.
            let middle = payload.len() / 2;
            if let Some(byte) = payload.get_mut(middle) {
                *byte ^= 0x10;
            }
        }
        let mut frame = cobs::encode_vec(&payload);
        frame.push(0);
        self.obs
            .write_all(&frame)
            .map_err(io("writing the observation link"))
    }

    /// The next message from the firmware.
    fn receive(&mut self) -> Result<FromController, HilError> {
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        loop {
            if let Some(end) = self.received.iter().position(|&b| b == 0) {
                let mut frame: Vec<u8> = self.received.drain(..=end).collect();
                let len = cobs::decode_in_place(&mut frame).map_err(|_| {
                    HilError::Protocol("a frame from the firmware is not COBS".into())
                })?;
                return wire::open::<FromController>(&frame[..len]).map_err(|e| {
                    HilError::Protocol(format!("a frame from the firmware was refused: {e:?}"))
                });
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(HilError::Protocol(format!(
                    "the firmware did not answer within {} s",
                    ANSWER_TIMEOUT.as_secs()
                )));
            }
            self.obs
                .set_read_timeout(Some(left.min(Duration::from_secs(1))))
                .map_err(io("the observation link"))?;
            let mut buf = [0u8; 4096];
            match self.obs.read(&mut buf) {
                Ok(0) => {
                    return Err(HilError::Protocol(
                        "QEMU closed the observation link".into(),
                    ))
                }
                Ok(n) => self.received.extend_from_slice(&buf[..n]),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    if let Ok(Some(status)) = self.qemu.try_wait() {
                        return Err(HilError::Protocol(format!("QEMU exited: {status}")));
                    }
                }
                Err(e) => return Err(io("reading the observation link")(e)),
            }
        }
    }

    /// The next message that is not a refusal of a corrupt frame (those are counted).
    fn answer(&mut self, rejected: &mut u32) -> Result<FromController, HilError> {
        loop {
            match self.receive()? {
                FromController::Rejected { .. } => *rejected += 1,
                other => return Ok(other),
            }
        }
    }
    /// Waits until the firmware has run `periods` more control periods (it holds the robot,
    /// or keeps it in safe stop, while it waits for the link); false if it did not in time.
    pub fn wait_periods(&self, periods: u64) -> bool {
        let until = self.plant().polls() + periods;
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        while self.plant().polls() < until {
            if Instant::now() > deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        true
    }

    /// Stops QEMU and the CAN link.
    pub fn shutdown(mut self) -> Result<(), HilError> {
        self.stop_qemu();
        if let Some(can) = self.can.take() {
            match can.join() {
                Ok(Ok(())) | Err(_) => {}
                Ok(Err(e)) => return Err(HilError::Io(e)),
            }
        }
        Ok(())
    }

    fn stop_qemu(&mut self) {
        let _ = self.qemu.kill();
        let _ = self.qemu.wait();
        let _ = std::fs::remove_dir_all(&self.scratch);
    }
}

impl Drop for Hil {
    fn drop(&mut self) {
        self.stop_qemu();
    }
}

/// The FIFO of the emulated clock's adapter bytes, in QEMU's working folder (the firmware's
/// `Emulated::FIFO`).
const ADAPTER_FIFO: &str = "adapter.fifo";

/// Makes the FIFO at `path` and opens it for reading and writing (Linux opens a FIFO so
/// without waiting for a reader; the host only writes).
fn make_fifo(path: &Path) -> Result<std::fs::File, HilError> {
    let made = std::process::Command::new("mkfifo")
        .arg(path)
        .status()
        .map_err(io("running mkfifo"))?;
    if !made.success() {
        return Err(HilError::Io(format!("mkfifo {} failed", path.display())));
    }
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .map_err(io("opening the adapter's FIFO"))
}

/// QEMU's semihosting for `clock`: the emulated clock's image reads its adapter's bytes by it.
fn semihosting(clock: PlantClock) -> &'static [&'static str] {
    match clock {
        PlantClock::Lockstep => &[],
        PlantClock::Emulated => &["-semihosting-config", "enable=on,target=native"],
    }
}

/// The adapter's side of the CAN UART: the firmware's lines to the plant, its answers back
/// (into the `fifo` on the emulated clock).
fn serve_can(
    mut stream: TcpStream,
    mut fifo: Option<std::fs::File>,
    plant: Arc<Mutex<Plant>>,
) -> Result<(), String> {
    let mut buf = [0u8; 4096];
    loop {
        let n = match stream.read(&mut buf) {
            Ok(0) => return Ok(()),
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            // QEMU killed at the end.
            Err(_) => return Ok(()),
        };
        let out = plant
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .feed(&buf[..n])
            .map_err(|e| format!("the CAN adapter: {e}"))?;
        let written = match fifo.as_mut() {
            Some(fifo) => fifo.write_all(&out),
            None => stream.write_all(&out),
        };
        if !out.is_empty() && written.is_err() {
            return Ok(());
        }
    }
}
