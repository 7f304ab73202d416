//! The wheel-legged robot's controller firmware, as a library the board's program runs.
//!
//! `#![no_std]`, no allocator, every buffer sized at compile time, nothing panics on data.
//! Two halves, both on the no_std runtime (`wheelleg_runtime`):
//! - [`stack`]: one decision: the int8 policy on the observation, the decision rule, the
//!   collision guard on the fine window and the arrival rule;
//! - [`control`]: the 100 Hz loop that drives a decision: setpoints to 16 ODrive axes over CAN,
//!   their feedback in, odometry and health, behind the [`control::Board`] trait, one period
//!   at a time so that a firmware runs it from a timer interrupt above the decision.
//!
//! Beside them: [`wire`], the observation link's frames (COBS, CRC-16, `postcard`), both ends;
//! [`link`], the once-only static buffers; `semihosting` (Arm targets), the emulator's files.
//!
//! Programs: for QEMU's mps2-an386 (Cortex-M4F), the production image `src/production/` (what
//! flash is measured on) and the check image `src/check/` (scripts/mcu.sh's vectors, counts
//! and kernel comparison); for a NUCLEO-G474RE, `board/`. docs/controller.md says how to
//! build, run and flash them.
#![no_std]

/// The 100 Hz control loop (the `wheelleg-control` crate, `control/`), under the path the
/// images and `board/` name it by.
pub use wheelleg_control as control;
pub mod link;
pub mod report;
#[cfg(target_arch = "arm")]
pub mod semihosting;
pub mod stack;
pub mod wire;
