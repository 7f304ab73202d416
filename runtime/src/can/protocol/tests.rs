use super::*;
use crate::can::frame::CanFrame;

fn node(n: u8) -> NodeId {
    NodeId::new(n).unwrap()
}

#[test]
fn set_input_pos_matches_the_dbc_layout() {
    let msg = Message::SetInputPos {
        pos_turns: 1.5,
        vel_ff_turns_per_s: -2.25,
        torque_ff_nm: 0.1,
    };
    let frame: CanFrame = encode(node(3), &msg).unwrap();
    assert_eq!(frame.raw_id(), 3 << 5 | 0x0C);
    let d = frame.data();
    assert_eq!(&d[0..4], &1.5f32.to_le_bytes());
    assert_eq!(i16::from_le_bytes([d[4], d[5]]), -2250);
    assert_eq!(i16::from_le_bytes([d[6], d[7]]), 100);
    assert_eq!(decode(&frame).unwrap(), (node(3), msg));
}

#[test]
fn every_message_round_trips() {
    let messages = [
        Message::Heartbeat {
            axis_error: axis_error::WATCHDOG_TIMER_EXPIRED,
            axis_state: AxisState::Idle,
        },
        Message::Estop,
        Message::SetAxisState(AxisState::ClosedLoopControl),
        Message::EncoderEstimates {
            pos_turns: -12.5,
            vel_turns_per_s: 3.0,
        },
        Message::SetControllerMode {
            control_mode: ControlMode::Velocity,
            input_mode: InputMode::Passthrough,
        },
        Message::SetInputVel {
            vel_turns_per_s: -7.5,
            torque_ff_nm: 0.0,
        },
        Message::ClearErrors,
        Message::Request(CmdId::GetEncoderEstimates),
        Message::Version(V0_5_6),
        Message::Request(CmdId::GetVersion),
    ];
    for msg in messages {
        let frame: CanFrame = encode(node(63), &msg).unwrap();
        assert_eq!(decode(&frame).unwrap(), (node(63), msg));
    }
}

const V0_5_6: Version = Version::ODRIVE_0_5_6;

#[test]
fn get_version_matches_odrive_0_6_layout() {
    let frame: CanFrame = encode(node(7), &Message::Version(V0_5_6)).unwrap();
    assert_eq!(frame.raw_id(), 7 << 5);
    assert!(!frame.is_remote_frame());
    // One byte each: protocol, hardware major.minor-variant, firmware major.minor.revision,
    // unreleased flag.
    assert_eq!(frame.data(), &[2, 3, 6, 56, 0, 5, 6, 0]);
    assert_eq!(decode(&frame).unwrap(), (node(7), Message::Version(V0_5_6)));
    assert!(V0_5_6.speaks_this_codec());
    let v0_6_11 = Version {
        fw_version_minor: 6,
        fw_version_revision: 11,
        ..V0_5_6
    };
    assert!(!v0_6_11.speaks_this_codec());
    assert!(!Version {
        fw_version_major: 1,
        ..V0_5_6
    }
    .speaks_this_codec());
    assert_eq!(text(v0_6_11).as_str(), "fw 0.6.11 (hw 3.6-56, protocol 2)");
}

#[test]
fn get_version_is_requested_with_a_remote_frame() {
    let request: CanFrame = encode(node(12), &Message::Request(CmdId::GetVersion)).unwrap();
    assert!(request.is_remote_frame());
    assert_eq!(request.raw_id(), 12 << 5);
    assert_eq!(request.dlc(), 8);
    assert!(request.data().is_empty());
    assert_eq!(
        decode(&request).unwrap(),
        (node(12), Message::Request(CmdId::GetVersion))
    );
    assert!(Message::Request(CmdId::GetVersion).is_command());
    assert!(!Message::Version(V0_5_6).is_command());
}

#[test]
fn a_short_get_version_answer_is_an_error() {
    for len in 0..8 {
        let frame = CanFrame::standard(4 << 5, &[0; 8][..len]).unwrap();
        assert_eq!(
            decode(&frame),
            Err(DecodeError::TooShort {
                cmd: CmdId::GetVersion,
                len: len as u8
            })
        );
    }
}

/// `x` formatted on the stack: the crate has no `alloc`, so no `to_string`.
fn text(x: impl core::fmt::Display) -> heapless::String<256> {
    let mut s = heapless::String::new();
    core::fmt::write(&mut s, format_args!("{x}")).unwrap();
    s
}

#[test]
fn heartbeat_state_reads_as_the_dbc_32_bit_field() {
    let frame: CanFrame = encode(
        node(1),
        &Message::Heartbeat {
            axis_error: 0,
            axis_state: AxisState::ClosedLoopControl,
        },
    )
    .unwrap();
    assert_eq!(u32_at(frame.data(), 4), 8);
}

#[test]
fn malformed_frames_are_errors_not_panics() {
    let short = CanFrame::standard(1 << 5 | 0x09, &[1, 2, 3]).unwrap();
    assert_eq!(
        decode(&short),
        Err(DecodeError::TooShort {
            cmd: CmdId::GetEncoderEstimates,
            len: 3
        })
    );
    let unknown = CanFrame::standard(1 << 5 | 0x1F, &[]).unwrap();
    assert_eq!(decode(&unknown), Err(DecodeError::UnknownCommand(0x1F)));
    let bad_state = CanFrame::standard(1 << 5 | 0x07, &[5, 0, 0, 0]).unwrap();
    assert_eq!(
        decode(&bad_state),
        Err(DecodeError::BadValue(CmdId::SetAxisState))
    );
    let mut nan_pos = [0u8; 8];
    nan_pos[..4].copy_from_slice(&f32::NAN.to_le_bytes());
    let nan_frame = CanFrame::standard(1 << 5 | 0x0C, &nan_pos).unwrap();
    assert_eq!(
        decode(&nan_frame),
        Err(DecodeError::BadValue(CmdId::SetInputPos))
    );
    let ext = CanFrame::new(embedded_can::ExtendedId::new(0x29).unwrap(), &[]).unwrap();
    assert_eq!(decode(&ext), Err(DecodeError::ExtendedId));
    let remote_cmd = CanFrame::new_remote(frame_id(node(2), CmdId::SetInputPos), 8).unwrap();
    assert_eq!(
        decode(&remote_cmd),
        Err(DecodeError::UnexpectedRemote(CmdId::SetInputPos))
    );
}

#[test]
fn out_of_range_values_are_refused_when_encoding() {
    let too_fast = Message::SetInputPos {
        pos_turns: 0.0,
        vel_ff_turns_per_s: 40.0,
        torque_ff_nm: 0.0,
    };
    assert_eq!(
        encode::<CanFrame>(node(1), &too_fast),
        Err(EncodeError::FeedForwardOutOfRange)
    );
    let nan = Message::SetInputVel {
        vel_turns_per_s: f32::NAN,
        torque_ff_nm: 0.0,
    };
    assert_eq!(
        encode::<CanFrame>(node(1), &nan),
        Err(EncodeError::NotFinite)
    );
    assert_eq!(NodeId::new(64), None);
}
