//! Robot descriptions: the robot a user has, as a file every tool reads.
//!
//! - [`description`]: `robots/NAME.toml` read into the runtime's [`Robot`](wheelleg_runtime::robot::Robot),
//!   and written back;
//! - [`validate`]: the rules a description meets, each error naming its key;
//! - [`reach`]: what the geometry allows (poses on the action lattice, the largest bar, the
//!   widest slab, the narrowest gap, the behaviours);
//! - [`urdf`]: URDF in (a robot of the paper's kind) and out.
//!
//! The method serves robots whose leg joints all turn about the body's x axis, so that body
//! clearance and wheel track are one coupled pair that all four legs share (docs/robot.md).

pub mod description;
pub mod reach;
pub mod urdf;
pub mod validate;

pub use description::{RobotDescription, SHIPPED_TOML};
pub use validate::DescriptionError;
