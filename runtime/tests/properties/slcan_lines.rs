//! SLCAN: every frame and command survives its line; any bytes decode without panicking.

use super::*;

fn any_slcan_command() -> impl Strategy<Value = slcan::Command> {
    use slcan::{BitRate, Command};
    prop_oneof![
        Just(Command::Open),
        Just(Command::ListenOnly),
        Just(Command::Close),
        Just(Command::Version),
        Just(Command::SerialNumber),
        Just(Command::StatusFlags),
        any::<bool>().prop_map(Command::Timestamps),
        prop::sample::select(BitRate::ALL.to_vec()).prop_map(Command::BitRate),
        any::<(u8, u8)>().prop_map(|(btr0, btr1)| Command::BitTiming { btr0, btr1 }),
        (any_frame(), prop::option::of(any::<u16>())).prop_map(|(frame, timestamp_ms)| {
            Command::Frame {
                frame,
                timestamp_ms,
            }
        }),
    ]
}

fn feed_line(
    decoder: &mut slcan::Decoder,
    bytes: &[u8],
) -> Vec<Result<Option<slcan::Command>, slcan::SlcanError>> {
    bytes.iter().map(|&b| decoder.feed(b)).collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8192))]

    /// Any frame, standard or extended, data or remote, with or without a timestamp, encodes
    /// to one CR-terminated line that decodes to the same frame.
    #[test]
    fn every_frame_round_trips_through_slcan(frame in any_frame(),
                                             timestamp_ms in prop::option::of(any::<u16>())) {
        let line = slcan::encode_frame(&frame, timestamp_ms).unwrap();
        let bytes = line.as_bytes();
        prop_assert!(bytes.len() <= slcan::LINE_CAPACITY);
        prop_assert_eq!(bytes.last(), Some(&slcan::CR));
        prop_assert!(bytes[..bytes.len() - 1].iter().all(|b| b.is_ascii_alphanumeric()));
        let mut decoder = slcan::Decoder::new();
        let results = feed_line(&mut decoder, bytes);
        prop_assert!(results[..results.len() - 1].iter().all(|r| *r == Ok(None)));
        prop_assert_eq!(results.last().copied(),
            Some(Ok(Some(slcan::Command::Frame { frame, timestamp_ms }))));
    }

    /// What an adapter sends a host (frames from the bus, every reply) decodes back to itself,
    /// interleaved in one stream.
    #[test]
    fn adapter_messages_round_trip_through_slcan(
        items in prop::collection::vec((any_frame(), prop::option::of(any::<u16>()),
                                        0u8..7, any::<(u8, u8)>()), 1..20)) {
        use slcan::{AdapterMessage, Reply};
        let mut decoder = slcan::Decoder::new();
        let (mut sent, mut got) = (Vec::new(), Vec::new());
        for (frame, timestamp_ms, kind, (a, b)) in items {
            let reply = match kind {
                0 => Reply::Ok,
                1 => Reply::Error,
                2 => Reply::Transmitted { extended: a % 2 == 1 },
                3 => Reply::Version { hardware: a % 100, software: b % 100 },
                4 => Reply::SerialNumber(*b"A1b2"),
                5 => Reply::StatusFlags(a),
                _ => Reply::Transmitted { extended: false },
            };
            sent.push(AdapterMessage::Frame { frame, timestamp_ms });
            sent.push(AdapterMessage::Reply(reply));
            let line = slcan::encode_frame(&frame, timestamp_ms).unwrap();
            for &byte in line.as_bytes().iter().chain(slcan::encode_reply(&reply).as_bytes()) {
                if let Some(m) = decoder.feed_from_adapter(byte).unwrap() {
                    got.push(m);
                }
            }
        }
        prop_assert_eq!(got, sent);
    }

    /// Every command a host sends decodes back to itself, many in one stream.
    #[test]
    fn every_command_round_trips_through_slcan(
        commands in prop::collection::vec(any_slcan_command(), 1..20)) {
        let mut decoder = slcan::Decoder::new();
        let mut decoded = Vec::new();
        for command in &commands {
            for result in feed_line(&mut decoder, slcan::encode_command(command).as_bytes()) {
                if let Some(c) = result.unwrap() {
                    decoded.push(c);
                }
            }
        }
        prop_assert_eq!(&decoded, &commands);
        prop_assert_eq!(decoder.stats().commands as usize, commands.len());
        prop_assert_eq!(decoder.stats().errors, 0);
    }

    /// Arbitrary bytes never panic; every error is counted; a well-formed line after any
    /// garbage and a CR still decodes; what decodes re-encodes to a line that decodes the same.
    #[test]
    fn any_bytes_decode_to_slcan_commands_or_counted_errors(
        garbage in prop::collection::vec(any::<u8>(), 0..200), frame in any_frame()) {
        let mut decoder = slcan::Decoder::new();
        let mut errors = 0u32;
        for result in feed_line(&mut decoder, &garbage) {
            match result {
                Err(_) => errors += 1,
                Ok(Some(command)) => {
                    let again = slcan::encode_command(&command);
                    let mut fresh = slcan::Decoder::new();
                    let back: Vec<_> = feed_line(&mut fresh, again.as_bytes())
                        .into_iter().filter_map(|r| r.unwrap()).collect();
                    prop_assert_eq!(back, vec![command]);
                }
                Ok(None) => {}
            }
        }
        prop_assert_eq!(decoder.stats().errors, errors);
        decoder.feed(slcan::CR).ok();
        let line = slcan::encode_frame(&frame, None).unwrap();
        let last = feed_line(&mut decoder, line.as_bytes()).pop();
        prop_assert_eq!(last, Some(Ok(Some(slcan::Command::Frame { frame, timestamp_ms: None }))));
    }
}
