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
use embedded_can::{ExtendedId, Frame, Id, StandardId};

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

/// The upper-case hex digit of the low 4 bits of `value`.
fn hex_digit(value: u32) -> u8 {
    let nibble = (value & 0xF) as u8;
    if nibble < 10 {
        b'0' + nibble
    } else {
        b'A' + nibble - 10
    }
}

/// The `t`/`T`/`r`/`R` line of any `embedded_can` frame, with a timestamp if given; an error
/// only for a frame type whose DLC or payload is over 8.
pub fn encode_frame<F: Frame>(frame: &F, timestamp_ms: Option<u16>) -> Result<Line, SlcanError> {
    let dlc = frame.dlc();
    if dlc > MAX_DATA_LEN || frame.data().len() > MAX_DATA_LEN {
        return Err(SlcanError::DlcOverEight(dlc.min(usize::from(u8::MAX)) as u8));
    }
    let mut line = Line::new();
    let remote = frame.is_remote_frame();
    match frame.id() {
        Id::Standard(id) => {
            line.push(if remote { b'r' } else { b't' });
            line.push_hex(u32::from(id.as_raw()), 3);
        }
        Id::Extended(id) => {
            line.push(if remote { b'R' } else { b'T' });
            line.push_hex(id.as_raw(), 8);
        }
    }
    line.push(hex_digit(dlc as u32));
    if !remote {
        for byte in frame.data() {
            line.push_hex(u32::from(*byte), 2);
        }
    }
    if let Some(ms) = timestamp_ms {
        line.push_hex(u32::from(ms), 4);
    }
    line.push(CR);
    Ok(line)
}

/// The line a host sends for `command` (what [`Decoder`] reads back as the same command).
pub fn encode_command(command: &Command) -> Line {
    let mut line = Line::new();
    match *command {
        Command::Open => line.push(b'O'),
        Command::ListenOnly => line.push(b'L'),
        Command::Close => line.push(b'C'),
        Command::BitRate(rate) => {
            line.push(b'S');
            line.push(b'0' + rate.code());
        }
        Command::BitTiming { btr0, btr1 } => {
            line.push(b's');
            line.push_hex(u32::from(btr0), 2);
            line.push_hex(u32::from(btr1), 2);
        }
        Command::Frame {
            frame,
            timestamp_ms,
        } => {
            // A CanFrame never has a DLC over 8, so this is the whole line.
            if let Ok(framed) = encode_frame(&frame, timestamp_ms) {
                return framed;
            }
        }
        Command::Version => line.push(b'V'),
        Command::SerialNumber => line.push(b'N'),
        Command::StatusFlags => line.push(b'F'),
        Command::Timestamps(on) => {
            line.push(b'Z');
            line.push(if on { b'1' } else { b'0' });
        }
    }
    line.push(CR);
    line
}

/// The bytes an adapter answers.
pub fn encode_reply(reply: &Reply) -> Line {
    let mut line = Line::new();
    match *reply {
        Reply::Ok => {}
        Reply::Error => {
            line.push(BEL);
            return line;
        }
        Reply::Transmitted { extended } => line.push(if extended { b'Z' } else { b'z' }),
        Reply::Version { hardware, software } => {
            line.push(b'V');
            for value in [hardware, software] {
                let value = value % 100;
                line.push(b'0' + value / 10);
                line.push(b'0' + value % 10);
            }
        }
        Reply::SerialNumber(serial) => {
            line.push(b'N');
            for c in serial {
                line.push(if c.is_ascii_alphanumeric() { c } else { b'0' });
            }
        }
        Reply::StatusFlags(flags) => {
            line.push(b'F');
            line.push_hex(u32::from(flags), 2);
        }
    }
    line.push(CR);
    line
}

/// Counters of what a [`Decoder`] read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct DecoderStats {
    /// Lines decoded to a command (from an adapter: to a reply or a frame; BEL included).
    pub commands: u32,
    /// Malformed lines (each was a [`SlcanError`]).
    pub errors: u32,
}

/// An incremental SLCAN line decoder: feed it bytes as they arrive, one at a time, with
/// [`Decoder::feed`] on an adapter (commands from a host) or [`Decoder::feed_from_adapter`] on a
/// host (replies and frames from an adapter).
#[derive(Clone, Debug)]
pub struct Decoder {
    line: [u8; MAX_LINE_LEN],
    len: usize,
    overlong: bool,
    after_cr: bool,
    stats: DecoderStats,
}

impl Default for Decoder {
    fn default() -> Self {
        Decoder::new()
    }
}

impl Decoder {
    /// A decoder at the start of a line.
    pub const fn new() -> Decoder {
        Decoder {
            line: [0; MAX_LINE_LEN],
            len: 0,
            overlong: false,
            after_cr: false,
            stats: DecoderStats {
                commands: 0,
                errors: 0,
            },
        }
    }

    /// What was decoded so far.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Adapter side: takes one byte from a host. `Ok(None)` mid-line and for empty lines; the
    /// command, or the error, when a CR ends the line.
    pub fn feed(&mut self, byte: u8) -> Result<Option<Command>, SlcanError> {
        if !self.accept(byte) {
            return Ok(None);
        }
        let result = if self.overlong {
            Err(SlcanError::LineTooLong)
        } else {
            decode_line(self.current())
        };
        self.end_line(result.as_ref().map(Option::is_some));
        result
    }

    /// Host side: takes one byte from an adapter. `Ok(None)` mid-line; a reply (BEL at once, the
    /// others and frames when their CR arrives) or the error of a malformed line.
    pub fn feed_from_adapter(&mut self, byte: u8) -> Result<Option<AdapterMessage>, SlcanError> {
        if byte == BEL {
            // BEL has no CR after it; a partial line before it stays and goes on.
            self.stats.commands = self.stats.commands.saturating_add(1);
            return Ok(Some(AdapterMessage::Reply(Reply::Error)));
        }
        if !self.accept(byte) {
            return Ok(None);
        }
        let result = if self.overlong {
            Err(SlcanError::LineTooLong)
        } else {
            decode_adapter_line(self.current())
        };
        self.end_line(result.as_ref().map(|_| true));
        result.map(Some)
    }

    /// Takes a byte into the line; true when it was the CR that ends the line.
    fn accept(&mut self, byte: u8) -> bool {
        let after_cr = core::mem::replace(&mut self.after_cr, false);
        match byte {
            CR => {
                self.after_cr = true;
                true
            }
            // CR LF line ends: the LF is no part of the next line.
            b'\n' if after_cr && self.len == 0 => false,
            _ => {
                match self.line.get_mut(self.len) {
                    Some(slot) => {
                        *slot = byte;
                        self.len += 1;
                    }
                    None => self.overlong = true,
                }
                false
            }
        }
    }

    fn current(&self) -> &[u8] {
        self.line.get(..self.len).unwrap_or(&[])
    }

    /// Starts the next line, counting the one that ended: `Ok(true)` a command, `Err` an error.
    fn end_line<E>(&mut self, decoded: Result<bool, E>) {
        self.len = 0;
        self.overlong = false;
        match decoded {
            Ok(false) => {}
            Ok(true) => self.stats.commands = self.stats.commands.saturating_add(1),
            Err(_) => self.stats.errors = self.stats.errors.saturating_add(1),
        }
    }
}

/// What an adapter sends a host: a reply to a command, or a frame from the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdapterMessage {
    /// CR, BEL, `z`, `Z`, `Vhhss`, `Nxxxx` or `Fxx`.
    Reply(Reply),
    /// A `t`, `T`, `r` or `R` line.
    Frame {
        /// The frame.
        frame: CanFrame,
        /// The adapter's millisecond timestamp, if it sends them (`Z1`).
        timestamp_ms: Option<u16>,
    },
}

/// Decodes one line an adapter sent, without its CR (BEL is not a line: see
/// [`Decoder::feed_from_adapter`]).
pub fn decode_adapter_line(line: &[u8]) -> Result<AdapterMessage, SlcanError> {
    if line.len() > MAX_LINE_LEN {
        return Err(SlcanError::LineTooLong);
    }
    let digit = |d: u8| {
        if d.is_ascii_digit() {
            Ok(d - b'0')
        } else {
            Err(SlcanError::BadArguments(b'V'))
        }
    };
    let reply = match line {
        [] => Reply::Ok,
        [b'z'] => Reply::Transmitted { extended: false },
        [b'Z'] => Reply::Transmitted { extended: true },
        &[b'V', h1, h0, s1, s0] => Reply::Version {
            hardware: 10 * digit(h1)? + digit(h0)?,
            software: 10 * digit(s1)? + digit(s0)?,
        },
        &[b'N', a, b, c, d] => Reply::SerialNumber([a, b, c, d]),
        [b'F', flags @ ..] if flags.len() == 2 => Reply::StatusFlags(hex(Some(flags))? as u8),
        [command @ (b't' | b'T' | b'r' | b'R'), args @ ..] => {
            return match parse_frame(*command, args)? {
                Command::Frame {
                    frame,
                    timestamp_ms,
                } => Ok(AdapterMessage::Frame {
                    frame,
                    timestamp_ms,
                }),
                _ => Err(SlcanError::UnknownCommand(*command)),
            }
        }
        [command @ (b'V' | b'N' | b'F'), ..] => return Err(SlcanError::BadArguments(*command)),
        [command, ..] => return Err(SlcanError::UnknownCommand(*command)),
    };
    Ok(AdapterMessage::Reply(reply))
}

/// Decodes one line without its CR (what [`Decoder`] does at each CR).
pub fn decode_line(line: &[u8]) -> Result<Option<Command>, SlcanError> {
    if line.len() > MAX_LINE_LEN {
        return Err(SlcanError::LineTooLong);
    }
    match line.split_first() {
        None => Ok(None),
        Some((&command, args)) => parse(command, args).map(Some),
    }
}

fn parse(command: u8, args: &[u8]) -> Result<Command, SlcanError> {
    let bare = |c: Command| {
        if args.is_empty() {
            Ok(c)
        } else {
            Err(SlcanError::BadArguments(command))
        }
    };
    match command {
        b'O' => bare(Command::Open),
        b'L' => bare(Command::ListenOnly),
        b'C' => bare(Command::Close),
        b'V' => bare(Command::Version),
        b'N' => bare(Command::SerialNumber),
        b'F' => bare(Command::StatusFlags),
        b'S' => match args {
            &[digit] => digit
                .checked_sub(b'0')
                .and_then(BitRate::from_code)
                .map(Command::BitRate)
                .ok_or(SlcanError::BadBitRate(digit)),
            _ => Err(SlcanError::BadArguments(command)),
        },
        b's' => match args {
            &[_, _, _, _] => Ok(Command::BitTiming {
                btr0: hex(args.get(0..2))? as u8,
                btr1: hex(args.get(2..4))? as u8,
            }),
            _ => Err(SlcanError::BadArguments(command)),
        },
        b'Z' => match args {
            b"0" => Ok(Command::Timestamps(false)),
            b"1" => Ok(Command::Timestamps(true)),
            &[flag] => Err(SlcanError::BadTimestampFlag(flag)),
            _ => Err(SlcanError::BadArguments(command)),
        },
        b't' | b'T' | b'r' | b'R' => parse_frame(command, args),
        b'd' | b'D' | b'b' | b'B' | b'Y' | b'M' | b'm' | b'U' | b'Q' | b'X' | b'W' | b'P'
        | b'A' => Err(SlcanError::Unsupported(command)),
        _ => Err(SlcanError::UnknownCommand(command)),
    }
}

fn parse_frame(command: u8, args: &[u8]) -> Result<Command, SlcanError> {
    let extended = command.is_ascii_uppercase();
    let remote = command.eq_ignore_ascii_case(&b'r');
    let id_digits = if extended { 8 } else { 3 };
    let too_short = || SlcanError::TooShort {
        command,
        len: (args.len() + 1).min(usize::from(u8::MAX)) as u8,
    };
    let raw = hex(Some(args.get(..id_digits).ok_or_else(too_short)?))?;
    let &dlc_digit = args.get(id_digits).ok_or_else(too_short)?;
    let dlc = hex_value(dlc_digit)?;
    if usize::from(dlc) > MAX_DATA_LEN {
        return Err(SlcanError::DlcOverEight(dlc));
    }
    let rest = args.get(id_digits + 1..).unwrap_or(&[]);
    let data_digits = if remote { 0 } else { 2 * usize::from(dlc) };
    let timestamp_ms = match rest.len() {
        n if n == data_digits => None,
        n if n == data_digits + 4 => Some(hex(rest.get(data_digits..))? as u16),
        n => {
            return Err(SlcanError::WrongDataLength {
                dlc,
                digits: n.min(usize::from(u8::MAX)) as u8,
            })
        }
    };
    let id: Id = if extended {
        if raw > MAX_EXTENDED_ID {
            return Err(SlcanError::IdOutOfRange { extended, raw });
        }
        ExtendedId::new(raw)
            .ok_or(SlcanError::IdOutOfRange { extended, raw })?
            .into()
    } else {
        if raw > MAX_STANDARD_ID {
            return Err(SlcanError::IdOutOfRange { extended, raw });
        }
        StandardId::new(raw as u16)
            .ok_or(SlcanError::IdOutOfRange { extended, raw })?
            .into()
    };
    let frame = if remote {
        CanFrame::new_remote(id, usize::from(dlc))
    } else {
        let mut data = [0u8; MAX_DATA_LEN];
        for (i, byte) in data.iter_mut().take(usize::from(dlc)).enumerate() {
            *byte = hex(rest.get(2 * i..2 * i + 2))? as u8;
        }
        CanFrame::new(id, data.get(..usize::from(dlc)).unwrap_or(&[]))
    };
    // The DLC was checked above, so the frame type accepts it.
    let frame = frame.ok_or(SlcanError::DlcOverEight(dlc))?;
    Ok(Command::Frame {
        frame,
        timestamp_ms,
    })
}

fn hex_value(digit: u8) -> Result<u8, SlcanError> {
    match digit {
        b'0'..=b'9' => Ok(digit - b'0'),
        b'A'..=b'F' => Ok(digit - b'A' + 10),
        b'a'..=b'f' => Ok(digit - b'a' + 10),
        _ => Err(SlcanError::BadHexDigit(digit)),
    }
}

/// The value of up to 8 hex digits (callers slice exactly the field).
fn hex(digits: Option<&[u8]>) -> Result<u32, SlcanError> {
    digits
        .unwrap_or(&[])
        .iter()
        .try_fold(0u32, |acc, &d| Ok((acc << 4) | u32::from(hex_value(d)?)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(bytes: &[u8]) -> ([Option<Result<Command, SlcanError>>; 8], Decoder) {
        let mut out = [None; 8];
        let mut n = 0;
        let mut decoder = Decoder::new();
        for &b in bytes {
            match decoder.feed(b) {
                Ok(None) => {}
                Ok(Some(c)) => {
                    out[n] = Some(Ok(c));
                    n += 1;
                }
                Err(e) => {
                    out[n] = Some(Err(e));
                    n += 1;
                }
            }
        }
        (out, decoder)
    }

    fn one(bytes: &[u8]) -> Result<Command, SlcanError> {
        let (out, decoder) = decode_all(bytes);
        assert!(out[1].is_none(), "more than one result from {bytes:?}");
        let result = out[0].expect("no result");
        let stats = decoder.stats();
        assert_eq!(
            (stats.commands, stats.errors),
            if result.is_ok() { (1, 0) } else { (0, 1) }
        );
        result
    }

    fn std_frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::standard(id, data).unwrap()
    }

    fn frame_command(frame: CanFrame) -> Command {
        Command::Frame {
            frame,
            timestamp_ms: None,
        }
    }

    #[test]
    fn control_commands_decode() {
        assert_eq!(one(b"O\r"), Ok(Command::Open));
        assert_eq!(one(b"L\r"), Ok(Command::ListenOnly));
        assert_eq!(one(b"C\r"), Ok(Command::Close));
        assert_eq!(one(b"V\r"), Ok(Command::Version));
        assert_eq!(one(b"N\r"), Ok(Command::SerialNumber));
        assert_eq!(one(b"F\r"), Ok(Command::StatusFlags));
        assert_eq!(one(b"Z1\r"), Ok(Command::Timestamps(true)));
        assert_eq!(one(b"Z0\r"), Ok(Command::Timestamps(false)));
        assert_eq!(
            one(b"s031C\r"),
            Ok(Command::BitTiming {
                btr0: 0x03,
                btr1: 0x1C
            })
        );
        for (code, rate) in BitRate::ALL.into_iter().enumerate() {
            let line = [b'S', b'0' + code as u8, CR];
            assert_eq!(one(&line), Ok(Command::BitRate(rate)));
            assert_eq!(encode_command(&Command::BitRate(rate)).as_bytes(), &line);
        }
        assert_eq!(BitRate::Mbps1.bits_per_s(), 1_000_000);
        assert_eq!(BitRate::from_code(9), None);
    }

    #[test]
    fn every_frame_kind_decodes_and_encodes() {
        let heartbeat = std_frame(0x1A1, &[0, 0, 0, 0, 8, 0, 0, 0]);
        assert_eq!(
            one(b"t1A180000000008000000\r"),
            Ok(frame_command(heartbeat))
        );
        assert_eq!(
            encode_frame(&heartbeat, None).unwrap().as_bytes(),
            b"t1A180000000008000000\r"
        );
        let estop = std_frame(0x1A2, &[]);
        assert_eq!(one(b"t1A20\r"), Ok(frame_command(estop)));
        assert_eq!(encode_frame(&estop, None).unwrap().as_bytes(), b"t1A20\r");
        let ext = CanFrame::new(ExtendedId::new(0x1234_5678).unwrap(), &[0xDE, 0xAD]).unwrap();
        assert_eq!(one(b"T123456782DEAD\r"), Ok(frame_command(ext)));
        assert_eq!(one(b"T123456782dead\r"), Ok(frame_command(ext)));
        assert_eq!(
            encode_frame(&ext, None).unwrap().as_bytes(),
            b"T123456782DEAD\r"
        );
        let rtr = CanFrame::new_remote(StandardId::new(0x1A9).unwrap(), 8).unwrap();
        assert_eq!(one(b"r1A98\r"), Ok(frame_command(rtr)));
        assert_eq!(encode_frame(&rtr, None).unwrap().as_bytes(), b"r1A98\r");
        let ext_rtr = CanFrame::new_remote(ExtendedId::new(0x1FFF_FFFF).unwrap(), 0).unwrap();
        assert_eq!(one(b"R1FFFFFFF0\r"), Ok(frame_command(ext_rtr)));
        assert_eq!(
            encode_frame(&ext_rtr, None).unwrap().as_bytes(),
            b"R1FFFFFFF0\r"
        );
        // With a millisecond timestamp after the data.
        let stamped = Command::Frame {
            frame: std_frame(0x7FF, &[0x11]),
            timestamp_ms: Some(0xEA5F),
        };
        assert_eq!(one(b"t7FF111EA5F\r"), Ok(stamped));
        assert_eq!(encode_command(&stamped).as_bytes(), b"t7FF111EA5F\r");
        let stamped_rtr = Command::Frame {
            frame: rtr,
            timestamp_ms: Some(1),
        };
        assert_eq!(one(b"r1A980001\r"), Ok(stamped_rtr));
    }

    #[test]
    fn replies_encode_as_lawicel_adapters_send_them() {
        assert_eq!(encode_reply(&Reply::Ok).as_bytes(), b"\r");
        assert_eq!(encode_reply(&Reply::Error).as_bytes(), &[BEL]);
        assert_eq!(
            encode_reply(&Reply::Transmitted { extended: false }).as_bytes(),
            b"z\r"
        );
        assert_eq!(
            encode_reply(&Reply::Transmitted { extended: true }).as_bytes(),
            b"Z\r"
        );
        assert_eq!(
            encode_reply(&Reply::Version {
                hardware: 1,
                software: 107
            })
            .as_bytes(),
            b"V0107\r"
        );
        assert_eq!(
            encode_reply(&Reply::SerialNumber(*b"W1-\x07")).as_bytes(),
            b"NW100\r"
        );
        assert_eq!(
            encode_reply(&Reply::StatusFlags(status_flag::DATA_OVERRUN)).as_bytes(),
            b"F08\r"
        );
    }

    #[test]
    fn empty_lines_and_crlf_are_no_commands() {
        let (out, decoder) = decode_all(b"\r\r\nO\r\nC\n\r");
        assert_eq!(out[0], Some(Ok(Command::Open)));
        // A LF that does not follow a CR is part of the line.
        assert_eq!(out[1], Some(Err(SlcanError::BadArguments(b'C'))));
        assert_eq!(out[2], None);
        assert_eq!(
            decoder.stats(),
            DecoderStats {
                commands: 1,
                errors: 1
            }
        );
        assert_eq!(decode_line(b""), Ok(None));
    }

    #[test]
    fn malformed_lines_are_typed_errors() {
        use SlcanError::*;
        assert_eq!(one(b"q\r"), Err(UnknownCommand(b'q')));
        assert_eq!(one(b"\x00\r"), Err(UnknownCommand(0)));
        assert_eq!(one(b"d1238\r"), Err(Unsupported(b'd')));
        assert_eq!(one(b"Y2\r"), Err(Unsupported(b'Y')));
        assert_eq!(one(b"M00000000\r"), Err(Unsupported(b'M')));
        assert_eq!(one(b"Ox\r"), Err(BadArguments(b'O')));
        assert_eq!(one(b"V1\r"), Err(BadArguments(b'V')));
        assert_eq!(one(b"S\r"), Err(BadArguments(b'S')));
        assert_eq!(one(b"S88\r"), Err(BadArguments(b'S')));
        assert_eq!(one(b"S9\r"), Err(BadBitRate(b'9')));
        assert_eq!(one(b"Sx\r"), Err(BadBitRate(b'x')));
        assert_eq!(one(b"s03\r"), Err(BadArguments(b's')));
        assert_eq!(one(b"s03G0\r"), Err(BadHexDigit(b'G')));
        assert_eq!(one(b"Z2\r"), Err(BadTimestampFlag(b'2')));
        assert_eq!(one(b"Z\r"), Err(BadArguments(b'Z')));
        // Frames: bad hex in id, DLC and data; DLC over 8; wrong data length; id too wide.
        assert_eq!(one(b"t1G20\r"), Err(BadHexDigit(b'G')));
        assert_eq!(one(b"t12x\r"), Err(BadHexDigit(b'x')));
        assert_eq!(one(b"t1231zz\r"), Err(BadHexDigit(b'z')));
        assert_eq!(one(b"t1239\r"), Err(DlcOverEight(9)));
        assert_eq!(one(b"T12345678F\r"), Err(DlcOverEight(15)));
        assert_eq!(
            one(b"t1232AABBCC\r"),
            Err(WrongDataLength { dlc: 2, digits: 6 })
        );
        assert_eq!(
            one(b"t1232AA\r"),
            Err(WrongDataLength { dlc: 2, digits: 2 })
        );
        assert_eq!(
            one(b"r1238AA\r"),
            Err(WrongDataLength { dlc: 8, digits: 2 })
        );
        assert_eq!(
            one(b"t8000\r"),
            Err(IdOutOfRange {
                extended: false,
                raw: 0x800
            })
        );
        assert_eq!(
            one(b"R200000000\r"),
            Err(IdOutOfRange {
                extended: true,
                raw: 0x2000_0000
            })
        );
        // A standard id written with 8 digits, an extended one with 3: the widths are wrong.
        assert_eq!(
            one(b"t000001230\r"),
            Err(WrongDataLength { dlc: 0, digits: 5 })
        );
        assert_eq!(
            one(b"T1230\r"),
            Err(TooShort {
                command: b'T',
                len: 5
            })
        );
        assert_eq!(
            one(b"t12\r"),
            Err(TooShort {
                command: b't',
                len: 3
            })
        );
        assert_eq!(
            one(b"t123\r"),
            Err(TooShort {
                command: b't',
                len: 4
            })
        );
    }

    #[test]
    fn overlong_lines_are_skipped_to_their_end_and_the_next_line_decodes() {
        let mut decoder = Decoder::new();
        for _ in 0..1000 {
            assert_eq!(decoder.feed(b'A'), Ok(None));
        }
        assert_eq!(decoder.feed(CR), Err(SlcanError::LineTooLong));
        for &b in b"t1A20" {
            assert_eq!(decoder.feed(b), Ok(None));
        }
        assert_eq!(
            decoder.feed(CR),
            Ok(Some(frame_command(std_frame(0x1A2, &[]))))
        );
        assert_eq!(
            decoder.stats(),
            DecoderStats {
                commands: 1,
                errors: 1
            }
        );
        // The longest valid line still fits.
        let longest = b"T1FFFFFFF80011223344556677FFFF\r";
        assert_eq!(longest.len(), LINE_CAPACITY);
        assert!(one(longest).is_ok());
        assert_eq!(
            decode_line(&[b'O'; MAX_LINE_LEN + 1]),
            Err(SlcanError::LineTooLong)
        );
    }

    #[test]
    fn a_host_decodes_what_an_adapter_sends() {
        let replies = [
            Reply::Ok,
            Reply::Error,
            Reply::Transmitted { extended: false },
            Reply::Transmitted { extended: true },
            Reply::Version {
                hardware: 12,
                software: 7,
            },
            Reply::SerialNumber(*b"AB12"),
            Reply::StatusFlags(0xA9),
        ];
        let mut decoder = Decoder::new();
        let mut got = [None; 8];
        let mut n = 0;
        let mut stream = [0u8; 64];
        let mut len = 0;
        for reply in replies {
            for &b in encode_reply(&reply).as_bytes() {
                stream[len] = b;
                len += 1;
            }
        }
        for &b in encode_frame(&std_frame(0x1A9, &[1, 2]), Some(0x0102))
            .unwrap()
            .as_bytes()
        {
            stream[len] = b;
            len += 1;
        }
        for &b in &stream[..len] {
            if let Some(m) = decoder.feed_from_adapter(b).unwrap() {
                got[n] = Some(m);
                n += 1;
            }
        }
        for (i, reply) in replies.into_iter().enumerate() {
            assert_eq!(got[i], Some(AdapterMessage::Reply(reply)));
        }
        assert_eq!(
            got[7],
            Some(AdapterMessage::Frame {
                frame: std_frame(0x1A9, &[1, 2]),
                timestamp_ms: Some(0x0102)
            })
        );
        assert_eq!(decoder.stats().commands, 8);
        // A BEL in the middle of a frame line (a refusal overtaking it) leaves the frame whole.
        let mut decoder = Decoder::new();
        let mut last = None;
        for &b in b"t1A\x0720\r" {
            if let Some(m) = decoder.feed_from_adapter(b).unwrap() {
                last = Some(m);
                if b == BEL {
                    assert_eq!(m, AdapterMessage::Reply(Reply::Error));
                }
            }
        }
        assert_eq!(
            last,
            Some(AdapterMessage::Frame {
                frame: std_frame(0x1A2, &[]),
                timestamp_ms: None
            })
        );
        use SlcanError::*;
        assert_eq!(decode_adapter_line(b"O"), Err(UnknownCommand(b'O')));
        assert_eq!(decode_adapter_line(b"V01x0"), Err(BadArguments(b'V')));
        assert_eq!(decode_adapter_line(b"V010"), Err(BadArguments(b'V')));
        assert_eq!(decode_adapter_line(b"N12"), Err(BadArguments(b'N')));
        assert_eq!(decode_adapter_line(b"FG0"), Err(BadHexDigit(b'G')));
        assert_eq!(decode_adapter_line(b"t1239"), Err(DlcOverEight(9)));
        assert_eq!(decode_adapter_line(&[b'z'; 40]), Err(LineTooLong));
    }

    #[test]
    fn frames_of_other_types_over_eight_bytes_are_refused_when_encoding() {
        struct Wide;
        impl Frame for Wide {
            fn new(_: impl Into<Id>, _: &[u8]) -> Option<Self> {
                None
            }
            fn new_remote(_: impl Into<Id>, _: usize) -> Option<Self> {
                None
            }
            fn is_extended(&self) -> bool {
                false
            }
            fn is_remote_frame(&self) -> bool {
                false
            }
            fn id(&self) -> Id {
                StandardId::ZERO.into()
            }
            fn dlc(&self) -> usize {
                12
            }
            fn data(&self) -> &[u8] {
                &[0; 12]
            }
        }
        assert_eq!(encode_frame(&Wide, None), Err(SlcanError::DlcOverEight(12)));
    }

    #[test]
    fn errors_name_what_is_wrong() {
        use core::fmt::Write;
        struct Buf([u8; 96], usize);
        impl Write for Buf {
            fn write_str(&mut self, s: &str) -> fmt::Result {
                for b in s.bytes() {
                    *self.0.get_mut(self.1).ok_or(fmt::Error)? = b;
                    self.1 += 1;
                }
                Ok(())
            }
        }
        let mut buf = Buf([0; 96], 0);
        write!(buf, "{}", SlcanError::WrongDataLength { dlc: 2, digits: 3 }).unwrap();
        assert_eq!(
            core::str::from_utf8(&buf.0[..buf.1]).unwrap(),
            "DLC 2 needs 4 data digits (or 4 more for a timestamp), got 3"
        );
    }
}
