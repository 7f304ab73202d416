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
    decode, encode, AxisState, CmdId, ControlMode, EncodeError, InputMode, Message, NodeId,
};
use wheelleg_runtime::can::slcan;
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::{IkError, JointAngles, LegConfig};
use wheelleg_runtime::model::format::{
    ActQuantRecord, ConvRecord, DenseRecord, Envelope, InputQuantRecord, InputRecord,
};
use wheelleg_runtime::model::quant::{requantize, to_int8, MAX_SHIFT, MIN_SHIFT};
use wheelleg_runtime::robot::WHEELLEG;

// ---------------------------------------------------------------------------------------------
// Leg kinematics

/// Tolerance of IK then FK: f32 trigonometry on links of 8 and 16 cm loses about 1e-6 m; 5e-6
/// leaves room without hiding a wrong formula (a wrong sign moves the wheel by centimetres).
const LEG_TOLERANCE_M: f32 = 5e-6;

fn any_config_in_limits() -> impl Strategy<Value = LegConfig> {
    let [c0, c1] = WHEELLEG.clearance_range_m;
    let [t0, t1] = WHEELLEG.track_range_m;
    (c0..=c1, t0..=t1).prop_map(|(clearance_m, track_m)| LegConfig {
        clearance_m,
        track_m,
    })
}

fn any_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        any::<f32>(),
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
        -1.0f32..1.0
    ]
}

proptest! {
    // About half the joint pairs land outside the command limits and are rejected.
    #![proptest_config(ProptestConfig { cases: 4096, max_global_rejects: 50_000,
                                        ..ProptestConfig::default() })]

    /// Every reachable configuration comes back from FK of its IK solution, with the wheel axle
    /// horizontal and the joints inside their ranges.
    #[test]
    fn ik_then_fk_returns_the_configuration(config in any_config_in_limits()) {
        if let Ok(joints) = WHEELLEG.leg_ik(config) {
            let back = WHEELLEG.config_from_joints(joints);
            prop_assert!((back.clearance_m - config.clearance_m).abs() < LEG_TOLERANCE_M,
                "{config:?} -> {joints:?} -> {back:?}");
            prop_assert!((back.track_m - config.track_m).abs() < LEG_TOLERANCE_M,
                "{config:?} -> {joints:?} -> {back:?}");
            let axle = joints.hip_rad + joints.knee_rad + joints.wheel_mount_rad;
            prop_assert!(axle.abs() < 1e-6);
            let [h0, h1] = WHEELLEG.hip_range_rad;
            let [k0, k1] = WHEELLEG.knee_range_rad;
            prop_assert!((h0 - 1e-5..=h1 + 1e-5).contains(&joints.hip_rad));
            prop_assert!((k0 - 1e-5..=k1 + 1e-5).contains(&joints.knee_rad));
        }
    }

    /// The reachable set is exactly the image of the joint ranges: any joint angles in range
    /// whose configuration lies in the command limits are found again by IK (IK is complete,
    /// not just sound). The knee is kept 0.05 rad off straight, where acos loses precision.
    #[test]
    fn fk_then_ik_returns_the_joints(hip in -1.2f32..1.5, knee in 0.05f32..2.8) {
        let joints = JointAngles { hip_rad: hip, knee_rad: knee, wheel_mount_rad: -(hip + knee) };
        let config = WHEELLEG.config_from_joints(joints);
        let [c0, c1] = WHEELLEG.clearance_range_m;
        let [t0, t1] = WHEELLEG.track_range_m;
        prop_assume!((c0..=c1).contains(&config.clearance_m) && (t0..=t1).contains(&config.track_m));
        let again = WHEELLEG.leg_ik(config);
        prop_assert!(again.is_ok(), "{joints:?} -> {config:?} -> {again:?}");
        let again = again.unwrap();
        prop_assert!((again.hip_rad - hip).abs() < 1e-3, "{joints:?} -> {again:?}");
        prop_assert!((again.knee_rad - knee).abs() < 1e-3, "{joints:?} -> {again:?}");
    }

    /// IK is total: any floats at all give finite angles or a reason, never NaN angles.
    #[test]
    fn ik_is_total(clearance_m in any_f32(), track_m in any_f32()) {
        match WHEELLEG.leg_ik(LegConfig { clearance_m, track_m }) {
            Ok(j) => prop_assert!(j.hip_rad.is_finite() && j.knee_rad.is_finite()
                && j.wheel_mount_rad.is_finite()),
            Err(IkError::NotFinite) => prop_assert!(!clearance_m.is_finite() || !track_m.is_finite()),
            Err(_) => {}
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Mecanum base

fn any_velocity() -> impl Strategy<Value = BaseVelocity> {
    (-2.0f32..2.0, -2.0f32..2.0, -4.0f32..4.0).prop_map(|(vx_mps, vy_mps, yaw_rate_radps)| {
        BaseVelocity {
            vx_mps,
            vy_mps,
            yaw_rate_radps,
        }
    })
}

fn close(a: f32, b: f32, scale: f32) -> bool {
    (a - b).abs() <= 1e-5 * scale.max(1.0)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4096))]

    /// Forward kinematics undoes inverse kinematics at every track the legs can hold.
    #[test]
    fn mecanum_forward_undoes_inverse(v in any_velocity(), track_m in 0.16f32..0.56) {
        let base = MecanumBase::new(&WHEELLEG, track_m).unwrap();
        let wheels = base.wheel_speeds(v).unwrap();
        let back = base.body_velocity(wheels).unwrap();
        prop_assert!(close(back.vx_mps, v.vx_mps, 2.0), "{v:?} -> {back:?}");
        prop_assert!(close(back.vy_mps, v.vy_mps, 2.0), "{v:?} -> {back:?}");
        prop_assert!(close(back.yaw_rate_radps, v.yaw_rate_radps, 4.0), "{v:?} -> {back:?}");
    }

    /// Odometry is the least-squares inverse: for any measured wheel speeds (slipping wheels
    /// included), the wheel speeds of the estimated velocity give the same estimate again, and
    /// the residual is orthogonal to every body motion (a slip does not bias the estimate).
    #[test]
    fn mecanum_odometry_is_a_projection(radps in prop::array::uniform4(-60.0f32..60.0),
                                        track_m in 0.16f32..0.56) {
        let base = MecanumBase::new(&WHEELLEG, track_m).unwrap();
        let measured = WheelSpeeds { radps };
        let v = base.body_velocity(measured).unwrap();
        let projected = base.wheel_speeds(v).unwrap();
        let again = base.body_velocity(projected).unwrap();
        prop_assert!(close(again.vx_mps, v.vx_mps, 3.0));
        prop_assert!(close(again.vy_mps, v.vy_mps, 3.0));
        prop_assert!(close(again.yaw_rate_radps, v.yaw_rate_radps, 10.0));
        let residual = WheelSpeeds {
            radps: core::array::from_fn(|i| measured.radps[i] - projected.radps[i]),
        };
        let bias = base.body_velocity(residual).unwrap();
        prop_assert!(bias.vx_mps.abs() < 1e-4 && bias.vy_mps.abs() < 1e-4
            && bias.yaw_rate_radps.abs() < 1e-3, "{bias:?}");
    }

    /// The speed scale keeps every wheel within its limit and scales no more than needed.
    #[test]
    fn speed_scale_respects_the_wheel_limit(v in any_velocity(), track_m in 0.16f32..0.56,
                                            limit in 1.0f32..60.0) {
        let base = MecanumBase::new(&WHEELLEG, track_m).unwrap();
        let s = base.speed_scale(v, limit).unwrap();
        prop_assert!(s > 0.0 && s <= 1.0);
        let scaled = BaseVelocity {
            vx_mps: s * v.vx_mps,
            vy_mps: s * v.vy_mps,
            yaw_rate_radps: s * v.yaw_rate_radps,
        };
        let peak = base.wheel_speeds(scaled).unwrap().max_abs_radps();
        prop_assert!(peak <= limit * (1.0 + 1e-5), "{peak} > {limit}");
        if s < 1.0 {
            prop_assert!(peak >= limit * (1.0 - 1e-4), "scaled down further than needed");
        }
    }

    /// Motor turns and joint angles convert both ways for every axis of the node map.
    #[test]
    fn node_map_conversions_round_trip(index in 0usize..16, angle in -6.0f32..6.0,
                                       offset in -5.0f32..5.0) {
        let axis = Axis::from_index(index).unwrap();
        let mut cal = NodeMap::NOMINAL.get(axis);
        cal.zero_offset_turns = offset;
        let back = cal.to_angle_rad(cal.to_motor_turns(angle));
        prop_assert!((back - angle).abs() < 1e-5 * 9.0 * 6.0, "{axis:?}: {angle} -> {back}");
        let speed = cal.to_speed_radps(cal.to_motor_turns_per_s(angle));
        prop_assert!((speed - angle).abs() < 1e-5);
    }
}

// ---------------------------------------------------------------------------------------------
// Fixed-point requantization

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8192))]

    /// `requantize` is the real product rounded half up, exactly, for every value, multiplier
    /// and shift the loader accepts (checked in i128 arithmetic, which cannot overflow).
    #[test]
    fn requantize_is_the_rounded_real_product(value in any::<i32>(),
                                              multiplier in 0i32..=i32::MAX,
                                              shift in MIN_SHIFT..=MAX_SHIFT) {
        let got = requantize(value, multiplier, shift);
        let right = 31 - i32::from(shift);
        let exact = i128::from(value) * i128::from(multiplier);
        // floor((exact + 2^(right-1)) / 2^right): round half towards +infinity.
        let want = (exact + (1i128 << (right - 1))).div_euclid(1i128 << right);
        prop_assert_eq!(i128::from(got), want);
    }

    /// The int8 output is clamped, and a fused ReLU never goes below the zero point.
    #[test]
    fn to_int8_stays_in_range(acc in any::<i32>(), multiplier in 0i32..=i32::MAX,
                              shift in MIN_SHIFT..=MAX_SHIFT, zero_point in any::<i8>(),
                              relu in any::<bool>()) {
        let q = to_int8(acc, multiplier, shift, zero_point, relu);
        if relu {
            prop_assert!(q >= zero_point);
        }
        let unclamped = requantize(acc, multiplier, shift) + i64::from(zero_point);
        if (-128..=127).contains(&unclamped) && (!relu || unclamped >= i64::from(zero_point)) {
            prop_assert_eq!(i64::from(q), unclamped);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Postcard round trips of the weights file's records

fn finite_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        any::<f32>().prop_filter("finite", |x| x.is_finite()),
        Just(0.0),
        Just(-0.0)
    ]
}

fn act_quant() -> impl Strategy<Value = ActQuantRecord> {
    (finite_f32(), any::<i8>()).prop_map(|(scale, zero_point)| ActQuantRecord { scale, zero_point })
}

fn input_quant() -> impl Strategy<Value = InputQuantRecord> {
    (finite_f32(), any::<i8>(), any::<i32>(), any::<i8>()).prop_map(
        |(scale_m, zero_point, multiplier, shift)| InputQuantRecord {
            scale_m,
            zero_point,
            multiplier,
            shift,
        },
    )
}

fn bytes(max: usize) -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<u8>(), 0..max)
}

/// Encodes with postcard into a stack buffer (the runtime has no allocator) and checks that
/// decoding gives the value back and consumes every byte.
fn round_trip<'a, T>(value: &T, buf: &'a mut [u8]) -> Result<T, TestCaseError>
where
    T: serde::Serialize + serde::Deserialize<'a> + PartialEq + core::fmt::Debug,
{
    let used = postcard::to_slice(value, buf).map_err(|e| TestCaseError::fail(format!("{e}")))?;
    let (back, rest) =
        postcard::take_from_bytes::<T>(used).map_err(|e| TestCaseError::fail(format!("{e}")))?;
    prop_assert!(rest.is_empty());
    prop_assert_eq!(&back, value);
    Ok(back)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2048))]

    #[test]
    fn envelope_round_trips(version in any::<u16>(), payload in bytes(600), crc in any::<[u8; 4]>()) {
        let envelope = Envelope { magic: *b"WLWM", version, payload: &payload, crc32_le: crc };
        let mut buf = [0u8; 1024];
        round_trip(&envelope, &mut buf)?;
    }

    #[test]
    fn input_records_round_trip(rows in any::<u16>(), cols in any::<u16>(), q in input_quant()) {
        let mut buf = [0u8; 64];
        round_trip(&InputRecord { rows, cols, height: q }, &mut buf)?;
        let mut buf = [0u8; 64];
        round_trip(&q, &mut buf)?;
    }

    #[test]
    fn conv_records_round_trip(shape in any::<(u16, u16, u8, u8, u8, bool)>(), output in act_quant(),
                               weights in bytes(300), bias in bytes(40), multipliers in bytes(40),
                               shifts in bytes(10)) {
        let (in_channels, out_channels, kernel, stride, padding, relu) = shape;
        let record = ConvRecord {
            in_channels, out_channels, kernel, stride, padding, relu, output,
            weights: &weights, bias: &bias, multipliers: &multipliers, shifts: &shifts,
        };
        let mut buf = [0u8; 1024];
        round_trip(&record, &mut buf)?;
    }

    #[test]
    fn dense_records_round_trip(shape in any::<(u16, u16, bool)>(), output in act_quant(),
                                weights in bytes(300), bias in bytes(40), multipliers in bytes(40),
                                shifts in bytes(10), head in any::<bool>()) {
        let (in_features, out_features, relu) = shape;
        let record = DenseRecord {
            in_features, out_features, relu, output,
            weights: &weights, bias: &bias, multipliers: &multipliers, shifts: &shifts,
        };
        let mut buf = [0u8; 1024];
        round_trip(&record, &mut buf)?;
        // The value head is stored as an Option.
        let optional = head.then_some(record);
        let mut buf = [0u8; 1024];
        round_trip(&optional, &mut buf)?;
    }
}

// ---------------------------------------------------------------------------------------------
// CAN: every CANSimple message round-trips; every frame that decodes re-encodes

fn node() -> impl Strategy<Value = NodeId> {
    (0u8..=63).prop_map(|n| NodeId::new(n).unwrap())
}

fn axis_state() -> impl Strategy<Value = AxisState> {
    prop::sample::select(
        (0u32..=13)
            .filter_map(AxisState::from_raw)
            .collect::<Vec<_>>(),
    )
}

/// Feed-forwards as they can travel: whole thousandths within the i16 field.
fn feed_forward() -> impl Strategy<Value = f32> {
    (i16::MIN..=i16::MAX).prop_map(|t| f32::from(t) / 1000.0)
}

fn message() -> impl Strategy<Value = Message> {
    let finite = || any::<f32>().prop_filter("finite", |x| x.is_finite());
    prop_oneof![
        (any::<u32>(), axis_state()).prop_map(|(axis_error, axis_state)| Message::Heartbeat {
            axis_error,
            axis_state
        }),
        Just(Message::Estop),
        axis_state().prop_map(Message::SetAxisState),
        (finite(), finite()).prop_map(|(pos_turns, vel_turns_per_s)| {
            Message::EncoderEstimates {
                pos_turns,
                vel_turns_per_s,
            }
        }),
        (0u32..=3, 0u32..=8).prop_map(|(c, i)| Message::SetControllerMode {
            control_mode: ControlMode::from_raw(c).unwrap(),
            input_mode: InputMode::from_raw(i).unwrap(),
        }),
        (finite(), feed_forward(), feed_forward()).prop_map(|(pos_turns, v, t)| {
            Message::SetInputPos {
                pos_turns,
                vel_ff_turns_per_s: v,
                torque_ff_nm: t,
            }
        }),
        (finite(), finite()).prop_map(|(vel_turns_per_s, torque_ff_nm)| {
            Message::SetInputVel {
                vel_turns_per_s,
                torque_ff_nm,
            }
        }),
        Just(Message::ClearErrors),
        prop::sample::select(vec![
            CmdId::Heartbeat,
            CmdId::GetEncoderEstimates,
            CmdId::GetMotorError,
            CmdId::GetEncoderError,
            CmdId::GetVbusVoltage,
        ])
        .prop_map(Message::Request),
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

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8192))]

    /// Every message of every node survives encode then decode unchanged, in a frame of the
    /// DBC's length with the id `node << 5 | cmd`.
    #[test]
    fn every_message_round_trips(node in node(), message in message()) {
        let frame: CanFrame = encode(node, &message).unwrap();
        prop_assert_eq!(frame.raw_id(), u32::from(node.get()) << 5 | message.cmd() as u32);
        prop_assert!(frame.is_standard());
        match message {
            Message::Estop | Message::ClearErrors => prop_assert_eq!(frame.dlc(), 0),
            _ => prop_assert_eq!(frame.dlc(), 8),
        }
        prop_assert_eq!(frame.is_remote_frame(), matches!(message, Message::Request(_)));
        prop_assert_eq!(decode(&frame), Ok((node, message)));
    }

    /// A received frame that decodes can be sent again as the same message: the decoder
    /// accepts nothing the encoder cannot produce.
    #[test]
    fn every_decoded_frame_re_encodes(frame in any_frame()) {
        if let Ok((node, message)) = decode(&frame) {
            let again: Result<CanFrame, _> = encode(node, &message);
            prop_assert!(again.is_ok(), "{frame:?} -> {message:?} -> {again:?}");
            prop_assert_eq!(decode(&again.unwrap()), Ok((node, message)));
        }
    }

    /// Set_Input_Pos frames with every feed-forward the i16 fields can hold, the extremes
    /// included (uniform frames almost never hit them), decode and re-encode unchanged.
    #[test]
    fn set_input_pos_feed_forwards_re_encode(node in node(), pos in -8.0f32..8.0,
        vel in prop_oneof![Just(i16::MIN), Just(i16::MAX), any::<i16>()],
        torque in prop_oneof![Just(i16::MIN), Just(i16::MAX), any::<i16>()]) {
        let mut data = [0u8; 8];
        data[..4].copy_from_slice(&pos.to_le_bytes());
        data[4..6].copy_from_slice(&vel.to_le_bytes());
        data[6..].copy_from_slice(&torque.to_le_bytes());
        let id = u16::from(node.get()) << 5 | CmdId::SetInputPos as u16;
        let frame = CanFrame::standard(id, &data).unwrap();
        let (_, message) = decode(&frame).unwrap();
        let again: Result<CanFrame, _> = encode(node, &message);
        prop_assert!(again.is_ok(), "{vel} {torque}: {again:?}");
        let again = again.unwrap();
        prop_assert_eq!(again.data(), &data[..]);
    }

    /// Values no frame can carry are refused at encoding, never silently wrapped.
    #[test]
    fn unencodable_values_are_refused(node in node(), bad in prop_oneof![
        Just(f32::NAN), Just(f32::INFINITY), Just(f32::NEG_INFINITY)
    ], too_big in 32.769f32..1e6) {
        let nan_vel = Message::SetInputVel { vel_turns_per_s: bad, torque_ff_nm: 0.0 };
        prop_assert_eq!(encode::<CanFrame>(node, &nan_vel), Err(EncodeError::NotFinite));
        let nan_pos = Message::EncoderEstimates { pos_turns: 0.0, vel_turns_per_s: bad };
        prop_assert_eq!(encode::<CanFrame>(node, &nan_pos), Err(EncodeError::NotFinite));
        for ff in [too_big, -too_big] {
            let msg = Message::SetInputPos { pos_turns: 0.0, vel_ff_turns_per_s: ff, torque_ff_nm: 0.0 };
            prop_assert_eq!(encode::<CanFrame>(node, &msg), Err(EncodeError::FeedForwardOutOfRange));
        }
    }
}

/// Regression (found by `set_input_pos_feed_forwards_re_encode`): a Set_Input_Pos whose
/// feed-forward field holds -32768 decoded to -32.768, which the encoder refused as out of
/// range, so a received command could not be sent again.
#[test]
fn the_lowest_feed_forward_re_encodes() {
    let node = NodeId::new(3).unwrap();
    let mut data = [0u8; 8];
    data[4..6].copy_from_slice(&i16::MIN.to_le_bytes());
    let frame = CanFrame::standard(3 << 5 | 0x0C, &data).unwrap();
    let (_, message) = decode(&frame).unwrap();
    let again: CanFrame = encode(node, &message).unwrap();
    assert_eq!(again.data(), &data[..]);
    let too_low = Message::SetInputPos {
        pos_turns: 0.0,
        vel_ff_turns_per_s: -32.7685,
        torque_ff_nm: 0.0,
    };
    assert_eq!(
        encode::<CanFrame>(node, &too_low),
        Err(EncodeError::FeedForwardOutOfRange)
    );
}

// ---------------------------------------------------------------------------------------------
// SLCAN: every frame and command survives its line; any bytes decode without panicking

fn any_slcan_command() -> impl Strategy<Value = slcan::Command> {
    use slcan::{BitRate, Command};
    prop_oneof![
        Just(Command::Open),
        Just(Command::ListenOnly),
        Just(Command::Close),
        Just(Command::Version),
        Just(Command::SerialNumber),
        Just(Command::StatusFlags),
        any::<bool>().prop_map(Command::Timestamps),
        prop::sample::select(BitRate::ALL.to_vec()).prop_map(Command::BitRate),
        any::<(u8, u8)>().prop_map(|(btr0, btr1)| Command::BitTiming { btr0, btr1 }),
        (any_frame(), prop::option::of(any::<u16>())).prop_map(|(frame, timestamp_ms)| {
            Command::Frame {
                frame,
                timestamp_ms,
            }
        }),
    ]
}

fn feed_line(
    decoder: &mut slcan::Decoder,
    bytes: &[u8],
) -> Vec<Result<Option<slcan::Command>, slcan::SlcanError>> {
    bytes.iter().map(|&b| decoder.feed(b)).collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8192))]

    /// Any frame, standard or extended, data or remote, with or without a timestamp, encodes
    /// to one CR-terminated line that decodes to the same frame.
    #[test]
    fn every_frame_round_trips_through_slcan(frame in any_frame(),
                                             timestamp_ms in prop::option::of(any::<u16>())) {
        let line = slcan::encode_frame(&frame, timestamp_ms).unwrap();
        let bytes = line.as_bytes();
        prop_assert!(bytes.len() <= slcan::LINE_CAPACITY);
        prop_assert_eq!(bytes.last(), Some(&slcan::CR));
        prop_assert!(bytes[..bytes.len() - 1].iter().all(|b| b.is_ascii_alphanumeric()));
        let mut decoder = slcan::Decoder::new();
        let results = feed_line(&mut decoder, bytes);
        prop_assert!(results[..results.len() - 1].iter().all(|r| *r == Ok(None)));
        prop_assert_eq!(results.last().copied(),
            Some(Ok(Some(slcan::Command::Frame { frame, timestamp_ms }))));
    }

    /// What an adapter sends a host (frames from the bus, every reply) decodes back to itself,
    /// interleaved in one stream.
    #[test]
    fn adapter_messages_round_trip_through_slcan(
        items in prop::collection::vec((any_frame(), prop::option::of(any::<u16>()),
                                        0u8..7, any::<(u8, u8)>()), 1..20)) {
        use slcan::{AdapterMessage, Reply};
        let mut decoder = slcan::Decoder::new();
        let (mut sent, mut got) = (Vec::new(), Vec::new());
        for (frame, timestamp_ms, kind, (a, b)) in items {
            let reply = match kind {
                0 => Reply::Ok,
                1 => Reply::Error,
                2 => Reply::Transmitted { extended: a % 2 == 1 },
                3 => Reply::Version { hardware: a % 100, software: b % 100 },
                4 => Reply::SerialNumber(*b"A1b2"),
                5 => Reply::StatusFlags(a),
                _ => Reply::Transmitted { extended: false },
            };
            sent.push(AdapterMessage::Frame { frame, timestamp_ms });
            sent.push(AdapterMessage::Reply(reply));
            let line = slcan::encode_frame(&frame, timestamp_ms).unwrap();
            for &byte in line.as_bytes().iter().chain(slcan::encode_reply(&reply).as_bytes()) {
                if let Some(m) = decoder.feed_from_adapter(byte).unwrap() {
                    got.push(m);
                }
            }
        }
        prop_assert_eq!(got, sent);
    }

    /// Every command a host sends decodes back to itself, many in one stream.
    #[test]
    fn every_command_round_trips_through_slcan(
        commands in prop::collection::vec(any_slcan_command(), 1..20)) {
        let mut decoder = slcan::Decoder::new();
        let mut decoded = Vec::new();
        for command in &commands {
            for result in feed_line(&mut decoder, slcan::encode_command(command).as_bytes()) {
                if let Some(c) = result.unwrap() {
                    decoded.push(c);
                }
            }
        }
        prop_assert_eq!(&decoded, &commands);
        prop_assert_eq!(decoder.stats().commands as usize, commands.len());
        prop_assert_eq!(decoder.stats().errors, 0);
    }

    /// Arbitrary bytes never panic; every error is counted; a well-formed line after any
    /// garbage and a CR still decodes; what decodes re-encodes to a line that decodes the same.
    #[test]
    fn any_bytes_decode_to_slcan_commands_or_counted_errors(
        garbage in prop::collection::vec(any::<u8>(), 0..200), frame in any_frame()) {
        let mut decoder = slcan::Decoder::new();
        let mut errors = 0u32;
        for result in feed_line(&mut decoder, &garbage) {
            match result {
                Err(_) => errors += 1,
                Ok(Some(command)) => {
                    let again = slcan::encode_command(&command);
                    let mut fresh = slcan::Decoder::new();
                    let back: Vec<_> = feed_line(&mut fresh, again.as_bytes())
                        .into_iter().filter_map(|r| r.unwrap()).collect();
                    prop_assert_eq!(back, vec![command]);
                }
                Ok(None) => {}
            }
        }
        prop_assert_eq!(decoder.stats().errors, errors);
        decoder.feed(slcan::CR).ok();
        let line = slcan::encode_frame(&frame, None).unwrap();
        let last = feed_line(&mut decoder, line.as_bytes()).pop();
        prop_assert_eq!(last, Some(Ok(Some(slcan::Command::Frame { frame, timestamp_ms: None }))));
    }
}

// ---------------------------------------------------------------------------------------------
// Collision guard

fn any_height_map_mm() -> impl Strategy<Value = Vec<i16>> {
    // Mostly bare ground with a few obstacles, plus the extremes a broken sensor sends.
    proptest::collection::vec(
        prop_oneof![
            8 => Just(0i16),
            2 => 1i16..600,
            1 => any::<i16>(),
        ],
        wheelleg_runtime::observation::HEIGHT_MAP_CELLS,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// On any height map, leg configuration, margin and action the guard answers without
    /// panicking, the strict check never passes what the lenient one refuses, and a guarded
    /// choice is always one of the 243 actions.
    #[test]
    fn the_guard_answers_anything(
        heights in any_height_map_mm(),
        clearance_m in any_f32(),
        track_m in any_f32(),
        margin_m in any_f32(),
        index in 0usize..wheelleg_runtime::action::COUNT,
    ) {
        use wheelleg_runtime::action::Action;
        use wheelleg_runtime::guard::{CollisionGuard, HeightMapRef};
        let guard = CollisionGuard::new(WHEELLEG, margin_m);
        let map: &[i16; wheelleg_runtime::observation::HEIGHT_MAP_CELLS] =
            heights.as_slice().try_into().unwrap();
        let legs = LegConfig { clearance_m, track_m };
        let action = Action::from_index(index).unwrap();
        let strict = guard.check(HeightMapRef::Millimetres(map), legs, action);
        let lenient = guard.check_no_deeper(HeightMapRef::Millimetres(map), legs, action);
        if lenient.is_err() {
            prop_assert!(strict.is_err());
        }
        let mut decider: wheelleg_runtime::decision::Decider<4> =
            wheelleg_runtime::decision::Decider::new();
        let logits = [0.0f32; 15];
        let checked = decider.choose_checked(
            wheelleg_runtime::decision::ObservationKey(1),
            &logits,
            CollisionGuard::LEVELS,
            |level, a| guard.allows(level, HeightMapRef::Millimetres(map), legs, a),
        );
        prop_assert!(checked.action.index() < wheelleg_runtime::action::COUNT);
    }
}
