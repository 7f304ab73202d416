//! Property tests of the math and codecs the controller relies on, over their whole input
//! ranges rather than hand-picked points: leg IK/FK over the reachable set, mecanum inverse and
//! forward kinematics, the node map's unit conversions, fixed-point requantization, postcard
//! round trips of the weights file's records, the collision guard on any input, CAN
//! encode/decode round trips for every CANSimple message, and SLCAN lines for every frame and
//! command (docs/robustness.md lists them with the tolerances and why).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::panic
)]

use embedded_can::{ExtendedId, Frame, StandardId};
use proptest::prelude::*;
use wheelleg_runtime::base::{BaseVelocity, MecanumBase, WheelSpeeds};
use wheelleg_runtime::can::node_map::{Axis, NodeMap};
use wheelleg_runtime::can::protocol::{
    decode, encode, AxisState, CmdId, ControlMode, EncodeError, InputMode, Message, NodeId, Version,
};
use wheelleg_runtime::can::slcan;
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::{IkError, JointAngles, LegConfig};
use wheelleg_runtime::model::format::{
    ActQuantRecord, ConvRecord, DenseRecord, Envelope, InputQuantRecord, InputRecord,
};
use wheelleg_runtime::model::quant::{requantize, to_int8, MAX_SHIFT, MIN_SHIFT};
use wheelleg_runtime::robot::WHEELLEG;

fn any_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        any::<f32>(),
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
        -1.0f32..1.0
    ]
}

/// Any classic CAN frame: standard or extended id, data or remote, 0 to 8 bytes.
fn any_frame() -> impl Strategy<Value = CanFrame> {
    (
        any::<bool>(),
        any::<bool>(),
        any::<u32>(),
        prop::collection::vec(any::<u8>(), 0..=8),
    )
        .prop_map(|(extended, remote, raw, data)| {
            let frame = match (extended, remote) {
                (false, false) => {
                    CanFrame::new(StandardId::new((raw & 0x7FF) as u16).unwrap(), &data)
                }
                (false, true) => {
                    CanFrame::new_remote(StandardId::new((raw & 0x7FF) as u16).unwrap(), data.len())
                }
                (true, false) => CanFrame::new(ExtendedId::new(raw & 0x1FFF_FFFF).unwrap(), &data),
                (true, true) => {
                    CanFrame::new_remote(ExtendedId::new(raw & 0x1FFF_FFFF).unwrap(), data.len())
                }
            };
            frame.unwrap()
        })
}

mod can;
mod fixed_point;
mod guard;
mod legs;
mod mecanum;
mod records;
mod slcan_lines;
