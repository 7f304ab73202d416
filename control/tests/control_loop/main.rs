//! The control loop against the 16 simulated ODrive axes on an in-process bus, one period at a
//! time through [`wheelleg_control::Control::period`]: the start-up and its roll call, a step's
//! setpoints and settling, a retreat, and the safe stop on every fault a board reports.
// A test fails by panicking: unwraps, indexing and panics are how it says what went wrong.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

mod safe_stop;
mod sim_board;
mod start_up;
mod steps;
