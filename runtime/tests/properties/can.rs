//! CAN: every CANSimple message round-trips; every frame that decodes re-encodes.

use super::*;

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
        any::<[u8; 8]>().prop_map(|b| Message::Version(Version::from_bytes(b))),
        prop::sample::select(vec![
            CmdId::GetVersion,
            CmdId::Heartbeat,
            CmdId::GetEncoderEstimates,
            CmdId::GetMotorError,
            CmdId::GetEncoderError,
            CmdId::GetVbusVoltage,
        ])
        .prop_map(Message::Request),
    ]
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
