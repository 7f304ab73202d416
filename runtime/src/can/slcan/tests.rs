use super::*;
use embedded_can::{ExtendedId, Id, StandardId};

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
