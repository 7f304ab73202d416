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
//! firmware's control periods in lockstep, or QEMU's instruction clock ([`plant`]); the world
//! moves as the in-process closed loop moves it ([`crate::closed_loop`]): after each step the
//! firmware reports its odometry and measured legs, the world checks them against the ideal
//! step with the same tolerances and snaps to the lattice, and a step the world refuses is
//! backed out of by the firmware (`Collided`).
//!
//! Pieces: starting QEMU, its links and the adapter's thread in `launch.rs`; the observation
//! link's host end in `link.rs`; an episode in `episode.rs`; what the host reads through
//! QEMU's monitor in `monitor.rs` (RAM in `memory.rs`); the images in `qemu.rs`; the faults
//! injected in `faults.rs`; the on-board stack as a host driver in [`onboard`].

mod episode;
mod faults;
mod launch;
mod link;
pub mod memory;
mod monitor;
pub mod onboard;
pub mod plant;
mod qemu;
#[path = "../../controller/src/wire.rs"]
pub mod wire;

pub use episode::HilEpisode;
pub use faults::{ControllerStop, Faults, LinkFault};
pub use monitor::instructions_per_systick_count;
pub use qemu::{
    default_image, find_or_build_image, image_for, image_with_weights, qemu_available,
    BUILD_COMMAND,
};

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
use wheelleg_runtime::robot::Robot;
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
    robot: Robot,
}

impl Hil {
    /// The motors and their adapter.
    pub fn plant(&self) -> MutexGuard<'_, Plant> {
        self.plant.lock().unwrap_or_else(|e| e.into_inner())
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
