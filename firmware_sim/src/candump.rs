//! Bus traffic as `candump -L` logs: writing, parsing and replaying.
//!
//! One frame per line, `(seconds.microseconds) interface id#data`, for example
//! `(1700000000.010000) can0 02C#0000803F00000000`: standard ids as 3 hex digits, extended ids
//! as 8, data as upper-case hex pairs, a remote frame as `#R` followed by its DLC when non-zero.
//! This is what can-utils' `candump -L` writes and `canplayer` reads, so a log from the
//! simulator can be replayed onto a real bus and vice versa.

use crate::bus::{BusError, Transport};
use embedded_can::{ExtendedId, Frame, Id, StandardId};
use std::fmt::Write as _;
use std::io::{self, Write};
use wheelleg_runtime::can::CanFrame;

/// Epoch of simulated time zero in logs (2023-11-14T22:13:20Z), so timestamps look like the
/// wall-clock ones candump writes and tools that expect them are not confused.
pub const DEFAULT_EPOCH_US: u64 = 1_700_000_000_000_000;

/// One logged frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LogEntry {
    /// Timestamp, microseconds since the Unix epoch.
    pub time_us: u64,
    /// Interface name (`can0`, `vcan0`).
    pub interface: String,
    /// The frame.
    pub frame: CanFrame,
}

/// Formats one log line (without the newline).
pub fn format_line(time_us: u64, interface: &str, frame: &CanFrame) -> String {
    let mut line = format!(
        "({}.{:06}) {} ",
        time_us / 1_000_000,
        time_us % 1_000_000,
        interface
    );
    // Writing into a String cannot fail.
    let _ = match frame.id() {
        Id::Standard(id) => write!(line, "{:03X}#", id.as_raw()),
        Id::Extended(id) => write!(line, "{:08X}#", id.as_raw()),
    };
    if frame.is_remote_frame() {
        line.push('R');
        if frame.dlc() > 0 {
            let _ = write!(line, "{}", frame.dlc());
        }
    } else {
        for b in frame.data() {
            let _ = write!(line, "{b:02X}");
        }
    }
    line
}

/// Why a log line could not be read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParseError {
    /// 1-based line number.
    pub line: usize,
    /// What was wrong.
    pub reason: &'static str,
}

impl std::fmt::Display for ParseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "candump log line {}: {}", self.line, self.reason)
    }
}

impl std::error::Error for ParseError {}

fn parse_timestamp(field: &str) -> Option<u64> {
    let inner = field.strip_prefix('(')?.strip_suffix(')')?;
    let (secs, frac) = inner.split_once('.')?;
    if frac.len() != 6 {
        return None;
    }
    let secs: u64 = secs.parse().ok()?;
    let micros: u64 = frac.parse().ok()?;
    secs.checked_mul(1_000_000)?.checked_add(micros)
}

fn parse_frame(field: &str) -> Result<CanFrame, &'static str> {
    let (id_hex, data_hex) = field.split_once('#').ok_or("no '#' in frame")?;
    let raw = u32::from_str_radix(id_hex, 16).map_err(|_| "bad id")?;
    let id: Id = match id_hex.len() {
        3 => StandardId::new(raw as u16)
            .ok_or("standard id over 0x7FF")?
            .into(),
        8 => ExtendedId::new(raw)
            .ok_or("extended id over 29 bits")?
            .into(),
        _ => return Err("id must have 3 or 8 hex digits"),
    };
    if let Some(dlc) = data_hex.strip_prefix('R') {
        let dlc = if dlc.is_empty() {
            0
        } else {
            dlc.parse::<usize>().map_err(|_| "bad remote DLC")?
        };
        return CanFrame::new_remote(id, dlc).ok_or("remote DLC over 8");
    }
    if data_hex.len() % 2 != 0 || data_hex.len() > 16 {
        return Err("data must be 0 to 8 hex byte pairs");
    }
    let mut data = [0u8; 8];
    for (i, byte) in data.iter_mut().take(data_hex.len() / 2).enumerate() {
        let pair = data_hex.get(2 * i..2 * i + 2).ok_or("bad data")?;
        *byte = u8::from_str_radix(pair, 16).map_err(|_| "bad data hex")?;
    }
    CanFrame::new(id, data.get(..data_hex.len() / 2).unwrap_or(&[])).ok_or("bad frame")
}

/// Parses one log line.
pub fn parse_line(line: &str, line_no: usize) -> Result<LogEntry, ParseError> {
    let err = |reason| ParseError {
        line: line_no,
        reason,
    };
    let mut fields = line.split_whitespace();
    let (Some(ts), Some(iface), Some(frame)) = (fields.next(), fields.next(), fields.next()) else {
        return Err(err("expected '(time) interface id#data'"));
    };
    Ok(LogEntry {
        time_us: parse_timestamp(ts).ok_or_else(|| err("bad timestamp"))?,
        interface: iface.to_owned(),
        frame: parse_frame(frame).map_err(err)?,
    })
}

/// Parses a whole log; blank lines are skipped, any other bad line is an error.
pub fn parse_log(text: &str) -> Result<Vec<LogEntry>, ParseError> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| parse_line(l, i + 1))
        .collect()
}

/// Writes frames to a `candump -L` log as they pass.
pub struct CandumpWriter<W: Write> {
    out: W,
    interface: String,
    epoch_us: u64,
    lines: u64,
}

impl<W: Write> CandumpWriter<W> {
    /// A writer stamping frames as `interface`, simulated time 0 at `epoch_us`.
    pub fn new(out: W, interface: &str, epoch_us: u64) -> Self {
        CandumpWriter {
            out,
            interface: interface.to_owned(),
            epoch_us,
            lines: 0,
        }
    }

    /// Logs one frame seen at simulated time `now_us`.
    pub fn log(&mut self, now_us: u64, frame: &CanFrame) -> io::Result<()> {
        self.lines += 1;
        writeln!(
            self.out,
            "{}",
            format_line(self.epoch_us + now_us, &self.interface, frame)
        )
    }

    /// Lines written so far.
    pub fn lines(&self) -> u64 {
        self.lines
    }

    /// Flushes and returns the underlying writer.
    pub fn finish(mut self) -> io::Result<W> {
        self.out.flush()?;
        Ok(self.out)
    }
}

/// Plays a log back as a [`Transport`]: frames arrive at their logged times, measured from the
/// first entry. What is sent to it is counted and discarded.
#[derive(Clone, Debug)]
pub struct Replay {
    entries: Vec<LogEntry>,
    next: usize,
    start_us: u64,
    /// Frames sent to the replay (ignored).
    pub sent: u64,
}

impl Replay {
    /// A replay of `entries` (in log order).
    pub fn new(entries: Vec<LogEntry>) -> Replay {
        let start_us = entries.first().map_or(0, |e| e.time_us);
        Replay {
            entries,
            next: 0,
            start_us,
            sent: 0,
        }
    }

    /// Whether every entry has been delivered.
    pub fn is_done(&self) -> bool {
        self.next >= self.entries.len()
    }
}

impl Transport for Replay {
    fn send(&mut self, _frame: &CanFrame, _now_us: u64) -> Result<(), BusError> {
        self.sent += 1;
        Ok(())
    }

    fn recv(&mut self, now_us: u64) -> Result<Option<CanFrame>, BusError> {
        match self.entries.get(self.next) {
            Some(e) if e.time_us.saturating_sub(self.start_us) <= now_us => {
                self.next += 1;
                Ok(Some(e.frame))
            }
            _ => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_match_candump_format_and_round_trip() {
        let f = CanFrame::standard(0x123, &[0xDE, 0xAD, 0xBE, 0xEF]).unwrap();
        let line = format_line(1_700_000_000_000_000, "can0", &f);
        assert_eq!(line, "(1700000000.000000) can0 123#DEADBEEF");
        assert_eq!(parse_line(&line, 1).unwrap().frame, f);
        let empty = CanFrame::standard(0x22, &[]).unwrap();
        assert_eq!(
            format_line(1_500_123, "vcan0", &empty),
            "(1.500123) vcan0 022#"
        );
        let remote = CanFrame::new_remote(StandardId::new(0x29).unwrap(), 8).unwrap();
        let line = format_line(0, "can0", &remote);
        assert_eq!(line, "(0.000000) can0 029#R8");
        assert_eq!(parse_line(&line, 1).unwrap().frame, remote);
        let ext = CanFrame::new(ExtendedId::new(0x1234567).unwrap(), &[1]).unwrap();
        let line = format_line(0, "can0", &ext);
        assert!(line.ends_with("01234567#01"), "{line}");
        assert_eq!(parse_line(&line, 1).unwrap().frame, ext);
    }

    #[test]
    fn bad_lines_are_reported_with_their_number() {
        let text = "(1.000000) can0 123#00\n\n(1.000001) can0 123#0\n";
        assert_eq!(
            parse_log(text),
            Err(ParseError {
                line: 3,
                reason: "data must be 0 to 8 hex byte pairs"
            })
        );
        assert!(parse_line("(1.0) can0 123#", 1).is_err());
        assert!(parse_line("(1.000000) can0 800#", 1).is_err());
        assert!(parse_line("(1.000000) can0 123#001122334455667788", 1).is_err());
        assert!(parse_line("garbage", 1).is_err());
    }

    #[test]
    fn replay_delivers_frames_at_their_logged_times() {
        let text = "(10.000000) can0 001#\n(10.005000) can0 002#\n(10.020000) can0 003#\n";
        let mut replay = Replay::new(parse_log(text).unwrap());
        assert_eq!(replay.recv(0).unwrap().unwrap().raw_id(), 1);
        assert_eq!(replay.recv(4_999).unwrap(), None);
        assert_eq!(replay.recv(5_000).unwrap().unwrap().raw_id(), 2);
        assert_eq!(replay.recv(30_000).unwrap().unwrap().raw_id(), 3);
        assert!(replay.is_done());
    }
}
