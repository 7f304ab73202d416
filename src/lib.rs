//! Library side of the `wheelleg` command: what the CLI and the whole-system tests (`tests/`)
//! share. The subcommands themselves stay in the binary (`src/cli/`).
//!
//! - [`closed_loop`]: the world simulator driving the simulated motors over CAN, and the world
//!   moved by what the motors measured (`wheelleg demo`).
//! - [`hil`]: the same loop with the controller firmware in QEMU between the world and the
//!   motors, on the serial links a robot has (`wheelleg demo --controller qemu`).

#![deny(missing_docs)]

pub mod closed_loop;
pub mod hil;
