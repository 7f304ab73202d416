//! SLCAN lines out: frames, a host's commands and an adapter's replies.

use super::*;
use embedded_can::Id;

/// The upper-case hex digit of the low 4 bits of `value`.
pub(super) fn hex_digit(value: u32) -> u8 {
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
