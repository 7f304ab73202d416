//! ODrive CANSimple messages: ids, payload layouts, encoding and decoding.
//!
//! Wire format (ODrive firmware 0.5.x, `third_party/odrive/odrive-cansimple.dbc`): an 11-bit standard id
//! `node_id << 5 | cmd_id`, payloads little-endian, floats IEEE-754 `f32`. The DBC lists every
//! message at node 0; a frame of node `n` has the DBC's id plus `n << 5`.
//!
//! | cmd  | message               | direction   | payload                                            |
//! |------|-----------------------|-------------|----------------------------------------------------|
//! | 0x00 | Get_Version           | axis → host | u8 each: protocol, hw major.minor.variant, fw major.minor.revision, unreleased |
//! | 0x01 | Heartbeat             | axis → host | u32 axis_error, u8 axis_state, 3 flag bytes        |
//! | 0x02 | Estop                 | host → axis | none                                               |
//! | 0x07 | Set_Axis_State        | host → axis | u32 requested state, 4 zero bytes                  |
//! | 0x09 | Get_Encoder_Estimates | axis → host | f32 pos (turns), f32 vel (turns/s)                 |
//! | 0x0B | Set_Controller_Mode   | host → axis | u32 control mode, u32 input mode                   |
//! | 0x0C | Set_Input_Pos         | host → axis | f32 pos (turns), i16 vel_ff ×1000, i16 torque_ff ×1000 |
//! | 0x0D | Set_Input_Vel         | host → axis | f32 vel (turns/s), f32 torque_ff (Nm)              |
//! | 0x18 | Clear_Errors          | host → axis | none                                               |
//!
//! A remote (RTR) frame with a `Get_*` id asks the axis to send that message now.
//!
//! Get_Version is ODrive 0.6's message (its 0.5.x DBC has no cmd 0x00): the host asks every node
//! for it at start-up and refuses firmware whose heartbeat layout is not the one above
//! ([`Version::speaks_this_codec`]), since the error bits moved between 0.5.x and 0.6.x.
//!
//! Decoding never panics: a frame that is extended, too short, carries an unknown command or an
//! out-of-range enum value is a [`DecodeError`], which callers count and drop.

mod states;

pub use states::{axis_error, AxisState, ControlMode, InputMode};

use embedded_can::{Frame, Id, StandardId};

/// Bits of the id that carry the command.
pub const CMD_BITS: u16 = 5;
/// Mask of the command bits in an id.
pub const CMD_MASK: u16 = (1 << CMD_BITS) - 1;
/// Largest node id (6 bits).
pub const MAX_NODE_ID: u8 = 0x3F;

/// A 6-bit ODrive node id (one per axis).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(u8);

impl NodeId {
    /// Node 0, the id of a factory-fresh ODrive.
    pub const MIN: NodeId = NodeId(0);

    /// A node id; `None` above [`MAX_NODE_ID`].
    pub const fn new(raw: u8) -> Option<NodeId> {
        if raw <= MAX_NODE_ID {
            Some(NodeId(raw))
        } else {
            None
        }
    }

    /// The raw id.
    pub const fn get(self) -> u8 {
        self.0
    }
}

/// CANSimple command ids (the low 5 bits of a frame id).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum CmdId {
    /// Protocol, hardware and firmware version, sent by the axis on request.
    GetVersion = 0x00,
    /// Axis state and errors, sent periodically by the axis.
    Heartbeat = 0x01,
    /// Emergency stop: the axis disarms and latches `ESTOP_REQUESTED`.
    Estop = 0x02,
    /// Request a motor error report.
    GetMotorError = 0x03,
    /// Request an encoder error report.
    GetEncoderError = 0x04,
    /// Request the axis state (idle, closed loop, ...).
    SetAxisState = 0x07,
    /// Position and velocity estimate, sent periodically by the axis.
    GetEncoderEstimates = 0x09,
    /// Control and input mode.
    SetControllerMode = 0x0B,
    /// Position setpoint with feed-forwards.
    SetInputPos = 0x0C,
    /// Velocity setpoint with torque feed-forward.
    SetInputVel = 0x0D,
    /// Bus voltage report.
    GetVbusVoltage = 0x17,
    /// Clear latched errors.
    ClearErrors = 0x18,
}

impl CmdId {
    /// The command with this 5-bit value, if this crate speaks it.
    pub const fn from_raw(raw: u8) -> Option<CmdId> {
        Some(match raw {
            0x00 => CmdId::GetVersion,
            0x01 => CmdId::Heartbeat,
            0x02 => CmdId::Estop,
            0x03 => CmdId::GetMotorError,
            0x04 => CmdId::GetEncoderError,
            0x07 => CmdId::SetAxisState,
            0x09 => CmdId::GetEncoderEstimates,
            0x0B => CmdId::SetControllerMode,
            0x0C => CmdId::SetInputPos,
            0x0D => CmdId::SetInputVel,
            0x17 => CmdId::GetVbusVoltage,
            0x18 => CmdId::ClearErrors,
            _ => return None,
        })
    }
}

/// The 11-bit id of command `cmd` for node `node`.
pub fn frame_id(node: NodeId, cmd: CmdId) -> StandardId {
    let raw = (u16::from(node.get()) << CMD_BITS) | cmd as u16;
    // node <= 63 and cmd < 32, so raw <= 0x7FF always fits; ZERO is unreachable.
    StandardId::new(raw).unwrap_or(StandardId::ZERO)
}

/// Largest magnitude the i16 ×1000 feed-forward fields of Set_Input_Pos can carry.
pub const MAX_FF: f32 = i16::MAX as f32 / 1000.0;

/// Firmware major.minor whose CANSimple layout this codec speaks (the table above).
pub const SPOKEN_FW_VERSION: (u8, u8) = (0, 5);

/// What an axis answers to Get_Version: the protocol, its hardware and its firmware.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub struct Version {
    /// Version of the CANSimple protocol itself.
    pub protocol_version: u8,
    /// Board major version (3 for an ODrive v3.6).
    pub hw_version_major: u8,
    /// Board minor version.
    pub hw_version_minor: u8,
    /// Board variant (for an ODrive v3.6: its voltage, 24 or 56).
    pub hw_version_variant: u8,
    /// Firmware major version.
    pub fw_version_major: u8,
    /// Firmware minor version.
    pub fw_version_minor: u8,
    /// Firmware revision.
    pub fw_version_revision: u8,
    /// Non-zero for a development build between releases.
    pub fw_version_unreleased: u8,
}

impl Version {
    /// An ODrive v3.6-56V on firmware 0.5.6, the release whose layout this codec speaks (which
    /// itself has no Get_Version: tools that simulate a newer board start from it).
    pub const ODRIVE_0_5_6: Version = Version {
        protocol_version: 2,
        hw_version_major: 3,
        hw_version_minor: 6,
        hw_version_variant: 56,
        fw_version_major: 0,
        fw_version_minor: 5,
        fw_version_revision: 6,
        fw_version_unreleased: 0,
    };

    /// Whether the firmware's major.minor is [`SPOKEN_FW_VERSION`]: any revision of it keeps
    /// the layout and error bits this codec decodes.
    pub const fn speaks_this_codec(&self) -> bool {
        self.fw_version_major == SPOKEN_FW_VERSION.0 && self.fw_version_minor == SPOKEN_FW_VERSION.1
    }

    /// The eight payload bytes, in wire order.
    pub const fn to_bytes(&self) -> [u8; 8] {
        [
            self.protocol_version,
            self.hw_version_major,
            self.hw_version_minor,
            self.hw_version_variant,
            self.fw_version_major,
            self.fw_version_minor,
            self.fw_version_revision,
            self.fw_version_unreleased,
        ]
    }

    /// The version carried by eight payload bytes.
    pub const fn from_bytes(bytes: [u8; 8]) -> Version {
        let [protocol, hw_major, hw_minor, hw_variant, fw_major, fw_minor, fw_revision, fw_dev] =
            bytes;
        Version {
            protocol_version: protocol,
            hw_version_major: hw_major,
            hw_version_minor: hw_minor,
            hw_version_variant: hw_variant,
            fw_version_major: fw_major,
            fw_version_minor: fw_minor,
            fw_version_revision: fw_revision,
            fw_version_unreleased: fw_dev,
        }
    }
}

impl core::fmt::Display for Version {
    /// `fw 0.5.6 (hw 3.6-56, protocol 2)`; a development build reads `fw 0.5.6-dev`.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "fw {}.{}.{}{} (hw {}.{}-{}, protocol {})",
            self.fw_version_major,
            self.fw_version_minor,
            self.fw_version_revision,
            if self.fw_version_unreleased != 0 {
                "-dev"
            } else {
                ""
            },
            self.hw_version_major,
            self.hw_version_minor,
            self.hw_version_variant,
            self.protocol_version
        )
    }
}

/// One CANSimple message, without its node id.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Message {
    /// The axis's protocol, hardware and firmware version (answer to a Get_Version request).
    Version(Version),
    /// Axis state and latched errors.
    Heartbeat {
        /// Latched axis error bits ([`axis_error`]).
        axis_error: u32,
        /// Current state.
        axis_state: AxisState,
    },
    /// Emergency stop.
    Estop,
    /// Request a state.
    SetAxisState(AxisState),
    /// Encoder estimate, motor side.
    EncoderEstimates {
        /// Position.
        pos_turns: f32,
        /// Velocity.
        vel_turns_per_s: f32,
    },
    /// Control and input mode.
    SetControllerMode {
        /// Control mode.
        control_mode: ControlMode,
        /// Input mode.
        input_mode: InputMode,
    },
    /// Position setpoint.
    SetInputPos {
        /// Target position.
        pos_turns: f32,
        /// Velocity feed-forward, carried as i16 thousandths: resolution 0.001 turn/s,
        /// magnitude at most [`MAX_FF`] (or exactly -32.768, the field's lowest value).
        vel_ff_turns_per_s: f32,
        /// Torque feed-forward, carried as i16 thousandths.
        torque_ff_nm: f32,
    },
    /// Velocity setpoint.
    SetInputVel {
        /// Target velocity.
        vel_turns_per_s: f32,
        /// Torque feed-forward.
        torque_ff_nm: f32,
    },
    /// Clear latched errors.
    ClearErrors,
    /// A remote (RTR) frame asking for the message with this command id.
    Request(CmdId),
}

impl Message {
    /// The message's command id.
    pub fn cmd(&self) -> CmdId {
        match self {
            Message::Version(_) => CmdId::GetVersion,
            Message::Heartbeat { .. } => CmdId::Heartbeat,
            Message::Estop => CmdId::Estop,
            Message::SetAxisState(_) => CmdId::SetAxisState,
            Message::EncoderEstimates { .. } => CmdId::GetEncoderEstimates,
            Message::SetControllerMode { .. } => CmdId::SetControllerMode,
            Message::SetInputPos { .. } => CmdId::SetInputPos,
            Message::SetInputVel { .. } => CmdId::SetInputVel,
            Message::ClearErrors => CmdId::ClearErrors,
            Message::Request(cmd) => *cmd,
        }
    }

    /// Whether the host sends this message to an axis (as opposed to an axis reporting).
    pub fn is_command(&self) -> bool {
        !matches!(
            self,
            Message::Version(_) | Message::Heartbeat { .. } | Message::EncoderEstimates { .. }
        )
    }
}

/// Why a message could not be put in a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EncodeError {
    /// A float is NaN or infinite.
    NotFinite,
    /// A feed-forward does not fit its i16 ×1000 field.
    FeedForwardOutOfRange,
    /// The frame type refused the id or payload.
    Frame,
}

/// Why a frame is not a valid CANSimple message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// Extended (29-bit) id: CANSimple uses standard ids only.
    ExtendedId,
    /// Command id this crate does not speak.
    UnknownCommand(u8),
    /// Payload shorter than the message needs.
    TooShort {
        /// The command.
        cmd: CmdId,
        /// Bytes received.
        len: u8,
    },
    /// An enum field holds a value ODrive does not define.
    BadValue(CmdId),
    /// A remote frame for a command that is not a request.
    UnexpectedRemote(CmdId),
}

fn f32_at(data: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(bytes_at(data, at))
}

fn u32_at(data: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(bytes_at(data, at))
}

fn i16_at(data: &[u8], at: usize) -> i16 {
    let mut b = [0u8; 2];
    if let Some(src) = data.get(at..at + 2) {
        b.copy_from_slice(src);
    }
    i16::from_le_bytes(b)
}

/// Four bytes at `at`, zeros if missing (callers check the length first).
fn bytes_at(data: &[u8], at: usize) -> [u8; 4] {
    let mut b = [0u8; 4];
    if let Some(src) = data.get(at..at + 4) {
        b.copy_from_slice(src);
    }
    b
}

fn put(buf: &mut [u8; 8], at: usize, bytes: &[u8]) {
    if let Some(dst) = buf.get_mut(at..at + bytes.len()) {
        dst.copy_from_slice(bytes);
    }
}

fn finite(x: f32) -> Result<f32, EncodeError> {
    if x.is_finite() {
        Ok(x)
    } else {
        Err(EncodeError::NotFinite)
    }
}

/// `x` in whole thousandths, if the i16 field holds it. The field's whole range is accepted,
/// -32.768 included (one step beyond -[`MAX_FF`]): whatever a received frame carries must be
/// sendable again, or a decoded command could not be relayed or logged back (found by the
/// property tests and the CAN fuzz target, docs/robustness.md).
fn thousandths(x: f32) -> Result<i16, EncodeError> {
    let t = libm::roundf(finite(x)? * 1000.0);
    if !(f32::from(i16::MIN)..=f32::from(i16::MAX)).contains(&t) {
        return Err(EncodeError::FeedForwardOutOfRange);
    }
    // In range and integral: the cast is exact.
    Ok(t as i16)
}

/// Builds the frame carrying `message` for `node`.
pub fn encode<F: Frame>(node: NodeId, message: &Message) -> Result<F, EncodeError> {
    let id = frame_id(node, message.cmd());
    let mut buf = [0u8; 8];
    let len = match *message {
        Message::Version(version) => {
            put(&mut buf, 0, &version.to_bytes());
            8
        }
        Message::Heartbeat {
            axis_error,
            axis_state,
        } => {
            put(&mut buf, 0, &axis_error.to_le_bytes());
            // Byte 4 is the state; bytes 5..8 are ODrive's flag bytes, which the simulated
            // axes leave clear, so the DBC's 32-bit Axis_State decodes to the state itself.
            put(&mut buf, 4, &[axis_state as u8]);
            8
        }
        Message::Estop | Message::ClearErrors => 0,
        Message::SetAxisState(state) => {
            put(&mut buf, 0, &(state as u32).to_le_bytes());
            // ODrive reads only the first 4 bytes, but its DBC declares 8: pad with zeros so
            // DBC-based tools decode the frame.
            8
        }
        Message::EncoderEstimates {
            pos_turns,
            vel_turns_per_s,
        } => {
            put(&mut buf, 0, &finite(pos_turns)?.to_le_bytes());
            put(&mut buf, 4, &finite(vel_turns_per_s)?.to_le_bytes());
            8
        }
        Message::SetControllerMode {
            control_mode,
            input_mode,
        } => {
            put(&mut buf, 0, &(control_mode as u32).to_le_bytes());
            put(&mut buf, 4, &(input_mode as u32).to_le_bytes());
            8
        }
        Message::SetInputPos {
            pos_turns,
            vel_ff_turns_per_s,
            torque_ff_nm,
        } => {
            put(&mut buf, 0, &finite(pos_turns)?.to_le_bytes());
            put(&mut buf, 4, &thousandths(vel_ff_turns_per_s)?.to_le_bytes());
            put(&mut buf, 6, &thousandths(torque_ff_nm)?.to_le_bytes());
            8
        }
        Message::SetInputVel {
            vel_turns_per_s,
            torque_ff_nm,
        } => {
            put(&mut buf, 0, &finite(vel_turns_per_s)?.to_le_bytes());
            put(&mut buf, 4, &finite(torque_ff_nm)?.to_le_bytes());
            8
        }
        Message::Request(_) => {
            // ODrive answers a remote frame of a Get_* id; the DLC announces an 8-byte reply.
            return F::new_remote(id, 8).ok_or(EncodeError::Frame);
        }
    };
    F::new(id, buf.get(..len).unwrap_or(&[])).ok_or(EncodeError::Frame)
}

/// Splits a frame into its node id and message.
pub fn decode<F: Frame>(frame: &F) -> Result<(NodeId, Message), DecodeError> {
    let raw = match frame.id() {
        Id::Standard(id) => id.as_raw(),
        Id::Extended(_) => return Err(DecodeError::ExtendedId),
    };
    // An 11-bit id shifted right by 5 is at most 63: always a valid node id.
    let node = NodeId((raw >> CMD_BITS) as u8);
    let cmd_raw = (raw & CMD_MASK) as u8;
    let cmd = CmdId::from_raw(cmd_raw).ok_or(DecodeError::UnknownCommand(cmd_raw))?;
    if frame.is_remote_frame() {
        return match cmd {
            CmdId::GetVersion
            | CmdId::Heartbeat
            | CmdId::GetEncoderEstimates
            | CmdId::GetMotorError
            | CmdId::GetEncoderError
            | CmdId::GetVbusVoltage => Ok((node, Message::Request(cmd))),
            _ => Err(DecodeError::UnexpectedRemote(cmd)),
        };
    }
    let data = frame.data();
    let need = |n: usize| {
        if data.len() >= n {
            Ok(())
        } else {
            Err(DecodeError::TooShort {
                cmd,
                len: data.len() as u8,
            })
        }
    };
    let message = match cmd {
        CmdId::GetVersion => {
            need(8)?;
            let mut bytes = [0u8; 8];
            if let Some(src) = data.get(..8) {
                bytes.copy_from_slice(src);
            }
            Message::Version(Version::from_bytes(bytes))
        }
        CmdId::Heartbeat => {
            need(5)?;
            let state = data.get(4).copied().unwrap_or(0);
            Message::Heartbeat {
                axis_error: u32_at(data, 0),
                axis_state: AxisState::from_raw(u32::from(state))
                    .ok_or(DecodeError::BadValue(cmd))?,
            }
        }
        CmdId::Estop => Message::Estop,
        CmdId::ClearErrors => Message::ClearErrors,
        CmdId::SetAxisState => {
            need(4)?;
            Message::SetAxisState(
                AxisState::from_raw(u32_at(data, 0)).ok_or(DecodeError::BadValue(cmd))?,
            )
        }
        CmdId::GetEncoderEstimates => {
            need(8)?;
            Message::EncoderEstimates {
                pos_turns: f32_at(data, 0),
                vel_turns_per_s: f32_at(data, 4),
            }
        }
        CmdId::SetControllerMode => {
            need(8)?;
            Message::SetControllerMode {
                control_mode: ControlMode::from_raw(u32_at(data, 0))
                    .ok_or(DecodeError::BadValue(cmd))?,
                input_mode: InputMode::from_raw(u32_at(data, 4))
                    .ok_or(DecodeError::BadValue(cmd))?,
            }
        }
        CmdId::SetInputPos => {
            need(8)?;
            Message::SetInputPos {
                pos_turns: f32_at(data, 0),
                vel_ff_turns_per_s: f32::from(i16_at(data, 4)) / 1000.0,
                torque_ff_nm: f32::from(i16_at(data, 6)) / 1000.0,
            }
        }
        CmdId::SetInputVel => {
            need(8)?;
            Message::SetInputVel {
                vel_turns_per_s: f32_at(data, 0),
                torque_ff_nm: f32_at(data, 4),
            }
        }
        // Reports this crate requests but never parses: a data frame of them is not expected.
        CmdId::GetMotorError | CmdId::GetEncoderError | CmdId::GetVbusVoltage => {
            return Err(DecodeError::UnknownCommand(cmd_raw))
        }
    };
    // A NaN or infinite float is never a meaningful setpoint or estimate; refusing it here
    // keeps every consumer from having to re-check.
    let floats_finite = match message {
        Message::EncoderEstimates {
            pos_turns: a,
            vel_turns_per_s: b,
        }
        | Message::SetInputVel {
            vel_turns_per_s: a,
            torque_ff_nm: b,
        } => a.is_finite() && b.is_finite(),
        Message::SetInputPos { pos_turns, .. } => pos_turns.is_finite(),
        _ => true,
    };
    if !floats_finite {
        return Err(DecodeError::BadValue(cmd));
    }
    Ok((node, message))
}

#[cfg(test)]
mod tests;
