//! The wheel-legged robot's controller firmware, as a library the board's program runs.
//!
//! `#![no_std]`, no allocator, every buffer sized at compile time, nothing panics on data.
//! Two halves, both on the no_std runtime (`wheelleg_runtime`):
//! - [`stack`]: one decision: the int8 policy on the observation, the decision rule, the
//!   collision guard on the fine window and the arrival rule;
//! - [`control`]: the 100 Hz loop that drives a decision: setpoints to 16 ODrive axes over CAN,
//!   their feedback in, odometry and health, behind the [`control::Board`] trait.
//!
//! The program for QEMU's mps2-an386 (Cortex-M4F) is `src/main.rs`; docs/controller.md says
//! how to build, run and flash it.
#![no_std]

pub mod control;
pub mod stack;
