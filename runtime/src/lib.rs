//! The wheel-legged robot as its controller sees it.
//!
//! `#![no_std]`, no `alloc`: every buffer has a size fixed at compile time, every fallible
//! operation returns a `Result`, nothing panics on data. This crate is the single source of truth
//! for what the robot *is* (its geometry, leg kinematics and action set): the simulator, the
//! trainer and the firmware simulator all take these definitions from here.
//!
//! - [`robot`]: dimensions of the body, legs and wheels.
//! - [`leg`]: 3-joint leg inverse and forward kinematics, and the reachable (clearance, track) set.
//! - [`action`]: the 5-D discrete action and its step sizes.
//! - [`decision`]: from the policy's heads to one action, never repeating a refused one.
//! - [`arrival`]: the last step: when one action reaches the target, the most probable such.
//! - [`guard`]: a look-ahead check of each action against the height map, before it is sent.
//! - [`observation`]: the height map's layout and the state vector the policy sees.
//! - [`model`]: the int8 policy network: weights file, loader, integer inference (scalar / AVX2).
//! - [`base`]: mecanum base kinematics, wheel speeds and odometry.
//! - [`motion`]: one decision as a smooth setpoint stream at the control rate.
//! - [`can`]: ODrive CANSimple commands and feedback for the 16 motor axes.
//! - [`trig`]: sine, cosine and isometries without `libm`'s large-argument reduction.
#![no_std]
#![deny(unsafe_code)]

pub mod action;
pub mod arrival;
pub mod base;
pub mod can;
pub mod decision;
pub mod guard;
pub mod leg;
pub mod model;
pub mod motion;
pub mod observation;
pub mod robot;
pub mod trig;
