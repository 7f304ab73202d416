//! The robot's CAN bus: ODrive CANSimple, wire-compatible with ODrive's own message database.
//!
//! - [`protocol`]: ids (`node_id << 5 | cmd_id`), payload layouts, encode and decode.
//! - [`node_map`]: which axis is which node; turns and gear ratios.
//! - [`host`]: the runtime's transmit queue, commands and feedback tracking.
//! - [`frame`]: a plain frame type for hosts and tests.
//! - [`bus_load`]: frame bit counts and bus load per control cycle.
//! - [`slcan`]: the Lawicel ASCII protocol of serial (USB) CAN adapters: encoder and line decoder.
//!
//! Everything is generic over [`embedded_can::Frame`], so any microcontroller HAL's CAN driver
//! (or SocketCAN on a Linux host) plugs in without conversion. docs/can-protocol.md documents the
//! node map, units, timing and bus load for people; docs/wheelleg.dbc does it for tools.

pub mod bus_load;
pub mod frame;
pub mod host;
pub mod node_map;
pub mod protocol;
pub mod slcan;

pub use frame::CanFrame;
pub use host::{Commander, FeedbackTracker, Health, TxQueue};
pub use node_map::{Axis, Joint, NodeMap};
pub use protocol::{decode, encode, Message, NodeId};
