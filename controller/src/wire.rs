//! The observation link's frames, both ends: the perception computer (the host) sends
//! observations, fine windows and collision reports; the controller answers with its decision,
//! the end of each step and why it stopped.
//!
//! Each frame is one `postcard` [`Envelope`] (a version byte, then the message), its CRC-16
//! (CRC-16/IBM-3740, little-endian) after it, all COBS-encoded and ended by a zero byte, so that a
//! receiver finds the next frame after any corruption. The height map and the fine window travel
//! as `postcard` byte strings of `i16` little-endian millimetres: a length, then the bytes as
//! they are, which the controller reads in place without copying.
//!
//! This file depends on `serde`, `postcard`, `cobs` and `crc` alone, so that the host's side of
//! the link (`src/hil`) compiles this very file and cannot disagree with the firmware on it.

use serde::{Deserialize, Serialize};

/// The link's version: a frame of another version is refused ([`WireError::Version`]).
pub const VERSION: u8 = 1;

/// The frames' checksum. Bitwise, without a table: the table would cost 512 bytes of flash, and
/// the controller checks about 13 KB per decision (some 0.5 M instructions, under a tenth of
/// the decision's).
pub const CRC: crc::Crc<u16, crc::NoTable> =
    crc::Crc::<u16, crc::NoTable>::new(&crc::CRC_16_IBM_3740);

/// Bytes of the checksum after the payload.
pub const CRC_BYTES: usize = 2;

/// The message of every frame, behind the link's version.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Envelope<M> {
    /// [`VERSION`].
    pub version: u8,
    /// The message.
    pub message: M,
}

/// What the perception computer sends the controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ToController<'a> {
    /// The observation of the next decision: the 32 x 32 height map (`i16` little-endian
    /// millimetres, row-major, 2,048 bytes) and the state (clearance, track, target x, target
    /// y in millimetres). The fine window follows once the controller asks for it.
    Observation {
        /// The first decision of an episode: the decision rule forgets the actions taken.
        new_episode: bool,
        /// The height map's bytes.
        #[serde(borrow)]
        height_mm_le: &'a [u8],
        /// Clearance, track, target x, target y.
        state_mm: [i32; 4],
    },
    /// The guard's fine window of the observation (`i16` little-endian millimetres, the
    /// stack's `window()` cells, row-major).
    Window {
        /// The window's bytes.
        #[serde(borrow)]
        heights_mm_le: &'a [u8],
    },
    /// The last step ran into something (the world refused it): back out of it along its
    /// inverse motion to where it started.
    Collided,
    /// A bring-up test of the real-time loop: the next decision first spends `ms`
    /// milliseconds busy (as a slow decision would), and the robot must hold through them.
    /// Nothing is answered.
    DelayNextDecision {
        /// The time to spend, in milliseconds.
        ms: u32,
    },
}

/// What the controller sends the perception computer.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum FromController {
    /// The observation arrived: send its fine window.
    WindowPlease,
    /// The decision on the observation (the firmware's decision record).
    Decision {
        /// The policy's int16 action logits.
        logits: [i16; 15],
        /// The greedy joint action.
        greedy: u8,
        /// The guard's strict verdict on it: 0 clear, 1 collision, 2 unreachable.
        greedy_verdict: u8,
        /// The action taken.
        action: u8,
        /// The guard's level that passed it, 255 if none did.
        level: u8,
        /// Candidates checked.
        checks: u16,
    },
    /// A step (or a retreat) is over and the robot holds its end pose.
    StepDone {
        /// False when the legs could not take the action: nothing was sent to the motors.
        moved: bool,
        /// Odometry since start-up: x, y in metres, yaw in radians.
        pose: [f32; 3],
        /// The measured legs: clearance, track in metres.
        legs_m: [f32; 2],
        /// Control periods since boot.
        tick: u32,
    },
    /// The controller holds the robot in safe stop (wheels stopped, legs held) for good.
    Stopped {
        /// Why: one of [`stop_reason`].
        reason: u8,
        /// For silent or errored axes, the axes as a bit mask over the node order.
        axes: u16,
        /// The control period (since boot) in which the controller stopped.
        tick: u32,
    },
    /// A frame was refused: one of [`WireError`] as its code.
    Rejected {
        /// [`WireError::code`].
        error: u8,
    },
    /// The decision ran past its deadline and was abandoned: no step, the robot holds. The
    /// next observation is decided afresh.
    DeadlineMissed {
        /// The control periods the decision ran before it was abandoned.
        periods: u32,
    },
}

/// Codes of [`FromController::Stopped`]'s reason.
pub mod stop_reason {
    /// Axes not heard from within the health timeout.
    pub const SILENT_AXES: u8 = 1;
    /// Axes reported errors.
    pub const AXIS_ERRORS: u8 = 2;
    /// The CAN adapter did not answer the period's status poll within its timeout.
    pub const CAN_LINK: u8 = 3;
    /// No observation (or window) within the observation timeout.
    pub const OBSERVATION_STALLED: u8 = 4;
    /// Only corrupt frames within the observation timeout.
    pub const OBSERVATION_CORRUPT: u8 = 5;
    /// Not every axis reached closed loop at start-up.
    pub const STARTUP_FAILED: u8 = 6;
    /// A step could not be driven (a motion the runtime cannot plan, a full transmit queue).
    pub const CONTROL: u8 = 7;
    /// An emergency stop was sent to every axis.
    pub const ESTOP: u8 = 8;
}

/// Why a frame is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WireError {
    /// Not valid COBS, or longer than the receiver's buffer.
    Framing,
    /// The checksum does not match.
    Checksum,
    /// Another version of the link.
    Version,
    /// The payload does not decode to a message, or has the wrong sizes.
    Message,
    /// The sender's buffer is too small for the frame.
    TooLong,
}

impl WireError {
    /// The code of [`FromController::Rejected`].
    pub fn code(self) -> u8 {
        self as u8 + 1
    }

    /// The error of a code, if it is one.
    pub fn from_code(code: u8) -> Option<WireError> {
        [
            WireError::Framing,
            WireError::Checksum,
            WireError::Version,
            WireError::Message,
            WireError::TooLong,
        ]
        .into_iter()
        .find(|e| e.code() == code)
    }
}

/// Checks a decoded frame's checksum and version and reads its message.
pub fn open<'a, M: Deserialize<'a>>(decoded: &'a [u8]) -> Result<M, WireError> {
    let split = decoded
        .len()
        .checked_sub(CRC_BYTES)
        .ok_or(WireError::Checksum)?;
    let (payload, crc) = decoded.split_at(split);
    if crc != CRC.checksum(payload).to_le_bytes() {
        return Err(WireError::Checksum);
    }
    let envelope: Envelope<M> = postcard::from_bytes(payload).map_err(|_| WireError::Message)?;
    if envelope.version != VERSION {
        return Err(WireError::Version);
    }
    Ok(envelope.message)
}

/// Writes `message` as one whole frame (COBS, its zero byte included) into `out` by way of
/// `scratch` (the payload and checksum before encoding); returns the frame's length.
pub fn seal<M: Serialize>(
    message: M,
    scratch: &mut [u8],
    out: &mut [u8],
) -> Result<usize, WireError> {
    let envelope = Envelope {
        version: VERSION,
        message,
    };
    let len = postcard::to_slice(&envelope, scratch)
        .map_err(|_| WireError::TooLong)?
        .len();
    let crc = CRC.checksum(scratch.get(..len).ok_or(WireError::TooLong)?);
    let with_crc = len + CRC_BYTES;
    scratch
        .get_mut(len..with_crc)
        .ok_or(WireError::TooLong)?
        .copy_from_slice(&crc.to_le_bytes());
    let source = scratch.get(..with_crc).ok_or(WireError::TooLong)?;
    let encoded = cobs::try_encode(source, out).map_err(|_| WireError::TooLong)?;
    *out.get_mut(encoded).ok_or(WireError::TooLong)? = 0;
    Ok(encoded + 1)
}

/// What one received byte completed ([`FrameReceiver::feed`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fed {
    /// The frame goes on.
    Nothing,
    /// A decoded frame of this many bytes is in the buffer.
    Frame(usize),
    /// A frame that is no frame (bad COBS, longer than the buffer); the next one starts afresh.
    Bad,
}

/// The receiving end of the link: COBS frames decoded into the caller's buffer as their bytes
/// come, whatever brings the bytes (a polled UART, a DMA ring).
#[derive(Debug)]
pub struct FrameReceiver {
    cobs: cobs::DecoderState,
    len: usize,
    too_long: bool,
}

impl Default for FrameReceiver {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameReceiver {
    /// Waiting for a frame's first byte.
    pub fn new() -> FrameReceiver {
        FrameReceiver {
            cobs: cobs::DecoderState::Idle,
            len: 0,
            too_long: false,
        }
    }

    /// Takes one byte into `buf` (the same buffer for every byte of a frame).
    pub fn feed(&mut self, byte: u8, buf: &mut [u8]) -> Fed {
        match self.cobs.feed(byte) {
            Ok(cobs::DecodeResult::NoData) => Fed::Nothing,
            Ok(cobs::DecodeResult::DataContinue(value)) => {
                match buf.get_mut(self.len) {
                    Some(slot) => *slot = value,
                    None => self.too_long = true,
                }
                self.len += 1;
                Fed::Nothing
            }
            Ok(cobs::DecodeResult::DataComplete) => {
                let len = core::mem::take(&mut self.len);
                if core::mem::take(&mut self.too_long) {
                    Fed::Bad
                } else {
                    Fed::Frame(len)
                }
            }
            Err(_) => {
                self.restart();
                Fed::Bad
            }
        }
    }

    /// Forgets the frame under way (bytes of it were lost).
    pub fn restart(&mut self) {
        *self = FrameReceiver::new();
    }
}
