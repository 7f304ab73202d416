//! The wheel-legged robot's controller firmware, as a library the board's program runs.
//!
//! `#![no_std]`, no allocator, every buffer sized at compile time, nothing panics on data.
//! Two halves, both on the no_std runtime (`wheelleg_runtime`):
//! - [`stack`]: one decision: the int8 policy on the observation, the decision rule, the
//!   collision guard on the fine window and the arrival rule;
//! - [`control`]: the 100 Hz loop that drives a decision: setpoints to 16 ODrive axes over CAN,
//!   their feedback in, odometry and health, behind the [`control::Board`] trait.
//!
//!
//! - [`wire`]: the observation link's frames (COBS, CRC-16, `postcard`), both ends.
//!
//! Two programs for QEMU's mps2-an386 (Cortex-M4F): the production image `src/production/`
//! (what flash is measured on) and the check image `src/check/` (scripts/mcu.sh's vectors,
//! counts and kernel comparison); docs/controller.md says how to build, run and flash them.
#![no_std]

pub mod control;
pub mod link;
pub mod stack;
pub mod wire;
