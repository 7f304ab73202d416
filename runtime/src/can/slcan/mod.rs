//! SLCAN (Lawicel ASCII), the serial protocol of cheap USB-CAN adapters: encoding and an
//! incremental line decoder.
//!
//! Every command is one line of printable ASCII ended by CR (0x0D); the adapter answers CR for
//! "done" and BEL (0x07) for "refused". Frames travel as hex in both directions:
//!
//! | line                 | meaning                                                          |
//! |----------------------|------------------------------------------------------------------|
//! | `O` / `L` / `C`      | open the channel / open it listen-only / close it                |
//! | `S0` … `S8`          | bit rate 10, 20, 50, 100, 125, 250, 500, 800 kbit/s, 1 Mbit/s    |
//! | `sXXYY`              | bit rate as SJA1000 BTR0/BTR1 register values                    |
//! | `tIIILDD…`           | data frame, 11-bit id `III`, DLC `L` (0-8), `2L` hex data digits |
//! | `TIIIIIIIILDD…`      | data frame, 29-bit id                                            |
//! | `rIIIL` / `RIIIIIIIIL` | remote frame, 11-bit / 29-bit id                               |
//! | `V` / `N` / `F`      | version (`Vhhss`), serial number (`Nxxxx`), status flags (`Fxx`) |
//! | `Z0` / `Z1`          | frames the adapter sends carry no / a 4-digit millisecond stamp  |
//!
//! A frame line may end in that 4-hex-digit timestamp; the decoder accepts and returns it. An
//! empty line (a lone CR) is no command: adapters treat it as a resynchronisation, and
//! python-can's `slcan` interface sends one after `Sn` when it sets no CAN FD data rate. A LF
//! right after a CR is ignored, so CR LF line ends work too. CAN FD (`d`, `D`, `b`, `B`, `Y`),
//! acceptance filters (`M`, `m`) and the adapter-configuration commands (`U`, `Q`, `X`, `W`,
//! `P`, `A`) are known and refused as [`SlcanError::Unsupported`].
//!
//! Both ends are here: an adapter decodes commands with [`Decoder::feed`] and answers with
//! [`encode_reply`] and [`encode_frame`]; a host sends [`encode_command`] lines and reads the
//! adapter's replies and frames with [`Decoder::feed_from_adapter`].
//!
//! Nothing here allocates or panics: lines are fixed buffers ([`Line`], at most
//! [`LINE_CAPACITY`] bytes), and every malformed line is a typed [`SlcanError`] the
//! [`Decoder`] counts; the adapter side answers it with [`Reply::Error`] (BEL).
//!
//! Why hand-written: the SLCAN crates on crates.io are `slcan` (std, tied to a serial-port
//! crate, last released 2020), `mini-slcan` (no_std, last released 2020), `mini-slcan-ng` (a
//! single 2024 release of a fork of it) and `serial-can` (a single 2024 release); none is
//! maintained, and none speaks this crate's [`CanFrame`] or counts its errors. The format is a
//! few fixed-width hex fields, so owning it costs less than depending on an abandoned crate.

use crate::can::frame::{CanFrame, MAX_DATA_LEN};
use core::fmt;
use embedded_can::Frame;

mod decode;
mod encode;
#[cfg(test)]
mod tests;

pub use decode::{decode_adapter_line, decode_line, AdapterMessage, Decoder, DecoderStats};
use encode::hex_digit;
pub use encode::{encode_command, encode_frame, encode_reply};

/// Line terminator of every command and of every reply but BEL.
pub const CR: u8 = b'\r';
/// The error reply.
pub const BEL: u8 = 0x07;
/// Longest valid line without its CR: `T`, 8 id digits, DLC, 16 data digits, 4 timestamp digits.
pub const MAX_LINE_LEN: usize = 1 + 8 + 1 + 2 * MAX_DATA_LEN + 4;
/// Room of a [`Line`]: the longest line and its CR.
pub const LINE_CAPACITY: usize = MAX_LINE_LEN + 1;
/// Largest 11-bit id.
const MAX_STANDARD_ID: u32 = 0x7FF;
/// Largest 29-bit id.
const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;

/// The standard bit rates of the `S0` … `S8` commands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BitRate {
    /// `S0`: 10 kbit/s.
    Kbps10,
    /// `S1`: 20 kbit/s.
    Kbps20,
    /// `S2`: 50 kbit/s.
    Kbps50,
    /// `S3`: 100 kbit/s.
    Kbps100,
    /// `S4`: 125 kbit/s.
    Kbps125,
    /// `S5`: 250 kbit/s.
    Kbps250,
    /// `S6`: 500 kbit/s.
    Kbps500,
    /// `S7`: 800 kbit/s in Lawicel's table (python-can calls it 750 kbit/s).
    Kbps800,
    /// `S8`: 1 Mbit/s, the robot's bus.
    Mbps1,
}

impl BitRate {
    /// All rates in command order (`S0` first).
    pub const ALL: [BitRate; 9] = [
        BitRate::Kbps10,
        BitRate::Kbps20,
        BitRate::Kbps50,
        BitRate::Kbps100,
        BitRate::Kbps125,
        BitRate::Kbps250,
        BitRate::Kbps500,
        BitRate::Kbps800,
        BitRate::Mbps1,
    ];

    /// The rate of `S<code>`; `None` for codes over 8.
    pub fn from_code(code: u8) -> Option<BitRate> {
        BitRate::ALL.get(usize::from(code)).copied()
    }

    /// The digit after `S`.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The rate in bit/s.
    pub const fn bits_per_s(self) -> u32 {
        match self {
            BitRate::Kbps10 => 10_000,
            BitRate::Kbps20 => 20_000,
            BitRate::Kbps50 => 50_000,
            BitRate::Kbps100 => 100_000,
            BitRate::Kbps125 => 125_000,
            BitRate::Kbps250 => 250_000,
            BitRate::Kbps500 => 500_000,
            BitRate::Kbps800 => 800_000,
            BitRate::Mbps1 => 1_000_000,
        }
    }
}

/// One decoded SLCAN line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// `O`: open the channel (send and receive).
    Open,
    /// `L`: open the channel listen-only (receive, never transmit).
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `S0` … `S8`: a standard bit rate.
    BitRate(BitRate),
    /// `sXXYY`: a bit rate as SJA1000 bus-timing register values.
    BitTiming {
        /// BTR0.
        btr0: u8,
        /// BTR1.
        btr1: u8,
    },
    /// `t`, `T`, `r`, `R`: a frame, with the adapter's millisecond timestamp if the line had one.
    Frame {
        /// The frame.
        frame: CanFrame,
        /// Milliseconds (Lawicel adapters count modulo 60,000).
        timestamp_ms: Option<u16>,
    },
    /// `V`: asks for the hardware and software version.
    Version,
    /// `N`: asks for the serial number.
    SerialNumber,
    /// `F`: asks for (and clears) the status flags.
    StatusFlags,
    /// `Z0` / `Z1`: frames sent to the host carry no / a millisecond timestamp.
    Timestamps(bool),
}

/// What an adapter answers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reply {
    /// CR: done.
    Ok,
    /// BEL: refused (malformed, unsupported, or not possible in the channel's state).
    Error,
    /// `z` CR / `Z` CR: a `t`/`r` (standard) or `T`/`R` (extended) frame was queued for the bus.
    Transmitted {
        /// Whether the frame had a 29-bit id.
        extended: bool,
    },
    /// `Vhhss` CR: hardware and software version, two decimal digits each (values over 99 are
    /// sent modulo 100).
    Version {
        /// Hardware version.
        hardware: u8,
        /// Software version.
        software: u8,
    },
    /// `Nxxxx` CR: four alphanumeric characters (anything else is sent as `0`).
    SerialNumber([u8; 4]),
    /// `Fxx` CR: status flags ([`status_flag`]).
    StatusFlags(u8),
}

/// Bits of the `F` reply (Lawicel's SJA1000 status register).
pub mod status_flag {
    /// The receive queue is full: frames for the host were lost.
    pub const RX_QUEUE_FULL: u8 = 0x01;
    /// The transmit queue is full.
    pub const TX_QUEUE_FULL: u8 = 0x02;
    /// Error warning.
    pub const ERROR_WARNING: u8 = 0x04;
    /// Data overrun.
    pub const DATA_OVERRUN: u8 = 0x08;
    /// Error passive.
    pub const ERROR_PASSIVE: u8 = 0x20;
    /// Arbitration lost.
    pub const ARBITRATION_LOST: u8 = 0x40;
    /// Bus error.
    pub const BUS_ERROR: u8 = 0x80;
}

/// Why a line is not a valid SLCAN command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SlcanError {
    /// More than [`MAX_LINE_LEN`] bytes before the CR (the rest of the line was skipped).
    LineTooLong,
    /// The first byte is no SLCAN command.
    UnknownCommand(u8),
    /// An SLCAN command this codec does not implement (CAN FD, acceptance filters, adapter
    /// configuration).
    Unsupported(u8),
    /// A command got arguments it does not take, or the wrong number of them.
    BadArguments(u8),
    /// A character where a hex digit must be.
    BadHexDigit(u8),
    /// `S` with something other than a digit 0-8.
    BadBitRate(u8),
    /// `Z` with something other than 0 or 1.
    BadTimestampFlag(u8),
    /// A frame's DLC over 8.
    DlcOverEight(u8),
    /// A frame line that ends before its id and DLC: `len` bytes of `command`.
    TooShort {
        /// The command (`t`, `T`, `r` or `R`).
        command: u8,
        /// Bytes in the line.
        len: u8,
    },
    /// A frame line whose data digits do not match its DLC (neither `2 * dlc` digits, nor
    /// that and a 4-digit timestamp).
    WrongDataLength {
        /// The DLC.
        dlc: u8,
        /// Hex digits after the DLC.
        digits: u8,
    },
    /// An id beyond 0x7FF (`t`, `r`) or 0x1FFFFFFF (`T`, `R`).
    IdOutOfRange {
        /// Whether the line was an extended-id one.
        extended: bool,
        /// The id read.
        raw: u32,
    },
}

impl fmt::Display for SlcanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ch = |b: &u8| char::from(*b).escape_default();
        match self {
            SlcanError::LineTooLong => {
                write!(f, "line longer than {MAX_LINE_LEN} characters")
            }
            SlcanError::UnknownCommand(c) => write!(f, "unknown command '{}'", ch(c)),
            SlcanError::Unsupported(c) => write!(f, "unsupported command '{}'", ch(c)),
            SlcanError::BadArguments(c) => write!(f, "wrong arguments for command '{}'", ch(c)),
            SlcanError::BadHexDigit(c) => write!(f, "'{}' is not a hex digit", ch(c)),
            SlcanError::BadBitRate(c) => write!(f, "bit rate 'S{}' is not S0-S8", ch(c)),
            SlcanError::BadTimestampFlag(c) => write!(f, "'Z{}' is not Z0 or Z1", ch(c)),
            SlcanError::DlcOverEight(d) => write!(f, "DLC {d} over 8"),
            SlcanError::TooShort { command, len } => write!(
                f,
                "'{}' line of {len} characters ends before its id and DLC",
                ch(command)
            ),
            SlcanError::WrongDataLength { dlc, digits } => write!(
                f,
                "DLC {dlc} needs {} data digits (or 4 more for a timestamp), got {digits}",
                2 * u32::from(*dlc)
            ),
            SlcanError::IdOutOfRange { extended, raw } => write!(
                f,
                "id {raw:#X} does not fit {} bits",
                if *extended { 29 } else { 11 }
            ),
        }
    }
}

/// One encoded line, CR included (BEL alone for [`Reply::Error`]).
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Line {
    buf: [u8; LINE_CAPACITY],
    len: usize,
}

impl Line {
    const fn new() -> Line {
        Line {
            buf: [0; LINE_CAPACITY],
            len: 0,
        }
    }

    /// The bytes to send.
    pub fn as_bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }

    // Every encoder writes at most LINE_CAPACITY bytes by construction; a byte beyond that
    // would be dropped rather than panic.
    fn push(&mut self, byte: u8) {
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = byte;
            self.len += 1;
        }
    }

    fn push_hex(&mut self, value: u32, digits: u32) {
        for shift in (0..digits).rev() {
            self.push(hex_digit(value >> (4 * shift)));
        }
    }
}

impl fmt::Debug for Line {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Line(\"")?;
        for b in self.as_bytes() {
            write!(f, "{}", char::from(*b).escape_default())?;
        }
        write!(f, "\")")
    }
}

impl AsRef<[u8]> for Line {
    fn as_ref(&self) -> &[u8] {
        self.as_bytes()
    }
}
