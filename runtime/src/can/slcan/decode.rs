//! SLCAN lines in: the incremental line decoder, commands for an adapter and the adapter's
//! replies and frames for a host.

use super::*;
use embedded_can::{ExtendedId, Id, StandardId};

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
