//! Simulated ODrive motor controllers on a CAN bus, and the closed loop through them.
//!
//! - [`axis`]: one ODrive-like axis (states, controller, first-order motor, watchdog, errors,
//!   periodic reports, silence as a fault).
//! - [`firmware`]: the robot's 16 axes behind one bus connection.
//! - [`bus`]: the [`bus::Transport`] trait and the in-process bus with fault injection (dropped,
//!   delayed, duplicated frames).
//! - [`socketcan`] (Linux, feature `socketcan`): the same trait over a SocketCAN interface.
//! - [`slcan`]: the bus behind an SLCAN (Lawicel ASCII) endpoint on TCP or a pseudo-terminal,
//!   as a USB-CAN adapter presents it to python-can, SavvyCAN or `slcand`.
//! - [`candump`]: `candump -L` log writing, parsing and replay.
//! - [`rig`]: runtime + bus + axes in one loop, reporting achieved against ideal steps.
//!
//! The protocol itself (ids, payloads, node map) is not here: it is the runtime's
//! (`wheelleg_runtime::can`), so the controller and the simulated motors cannot disagree on it.

pub mod axis;
pub mod bus;
pub mod candump;
pub mod firmware;
pub mod rig;
pub mod slcan;
#[cfg(all(feature = "socketcan", target_os = "linux"))]
pub mod socketcan;
