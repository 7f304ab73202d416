use super::*;

fn adapter_after(bytes: &[u8]) -> SlcanAdapter {
    let mut s = SlcanAdapter::new();
    s.receive_bytes(bytes);
    s
}

#[test]
fn endpoint_specs_parse_or_say_what_is_wrong() {
    assert_eq!(
        "tcp:127.0.0.1:20108".parse(),
        Ok(EndpointSpec::Tcp("127.0.0.1:20108".into()))
    );
    assert_eq!(
        "tcp:[::1]:0".parse(),
        Ok(EndpointSpec::Tcp("[::1]:0".into()))
    );
    assert_eq!("pty".parse(), Ok(EndpointSpec::Pty));
    let err = |s: &str| s.parse::<EndpointSpec>().unwrap_err().to_string();
    assert!(err("serial").contains("neither tcp:HOST:PORT nor pty"));
    assert!(err("tcp:20108").contains("needs a host and a port"));
    assert!(err("tcp:localhost:http").contains("port 'http' is not a number"));
    assert!(err("tcp:localhost:70000").contains("port '70000'"));
}

#[test]
fn python_can_open_sequence_opens_the_channel() {
    // python-can with bitrate=1000000: close, bit rate, an empty line, open, open again.
    let s = adapter_after(b"C\rS8\r\rO\rO\r");
    assert_eq!(s.channel(), ChannelState::Open);
    assert_eq!(s.bit_rate(), Some(BitRate::Mbps1));
    assert_eq!(s.pending_output(), b"\r\r\r\r");
    assert_eq!(s.stats().malformed + s.stats().refused, 0);
}

#[test]
fn frames_pass_only_while_the_channel_is_open() {
    let mut s = adapter_after(b"t1A20\r");
    assert_eq!(s.next_frame(), None);
    assert_eq!(s.pending_output(), [0x07]);
    assert_eq!(s.stats().refused, 1);
    let hb = CanFrame::standard(0x1A1, &[0, 0, 0, 0, 1, 0, 0, 0]).unwrap();
    assert!(!s.frame_to_client(&hb, 0));
    s.consume_output(1);
    s.receive_bytes(b"O\rt1A20\rT000001A20\r");
    assert_eq!(s.pending_output(), b"\rz\rZ\r");
    assert_eq!(s.next_frame(), CanFrame::standard(0x1A2, &[]));
    assert!(s.next_frame().unwrap().raw_id() == 0x1A2);
    s.consume_output(5);
    assert!(s.frame_to_client(&hb, 0));
    assert_eq!(s.pending_output(), b"t1A180000000001000000\r");
    assert_eq!(s.stats().frames_from_client, 2);
    assert_eq!(s.stats().frames_to_client, 1);
}

#[test]
fn listen_only_receives_but_refuses_to_transmit() {
    let mut s = adapter_after(b"L\rt1A20\r");
    assert_eq!(s.channel(), ChannelState::ListenOnly);
    assert_eq!(s.pending_output(), b"\r\x07");
    assert_eq!(s.next_frame(), None);
    let hb = CanFrame::standard(0x1A1, &[0; 8]).unwrap();
    assert!(s.frame_to_client(&hb, 0));
}

#[test]
fn state_rules_match_a_lawicel_adapter() {
    // C when closed is fine; O twice too; L on an open channel, S and s while open are
    // refused; after C they are accepted; O on a listen-only channel is refused.
    let s = adapter_after(b"C\rO\rO\rL\rS6\rs031C\rC\rS6\rs031C\rL\rL\rO\r");
    assert_eq!(s.pending_output(), b"\r\r\r\x07\x07\x07\r\r\r\r\r\x07");
    assert_eq!(s.bit_rate(), Some(BitRate::Kbps500));
    assert_eq!(s.stats().refused, 4);
    assert_eq!(s.channel(), ChannelState::ListenOnly);
}

#[test]
fn version_serial_number_and_status_flags_answer() {
    let mut s = adapter_after(b"V\rN\rF\r");
    assert_eq!(s.pending_output(), b"V0100\rNWLSM\rF00\r");
    s.consume_output(usize::MAX);
    s.receive_bytes(b"O\r");
    s.consume_output(usize::MAX);
    // A client that never reads: the queue fills, frames are dropped and flagged.
    let hb = CanFrame::standard(0x1A1, &[0; 8]).unwrap();
    let mut queued = 0;
    for _ in 0..5000 {
        queued += usize::from(s.frame_to_client(&hb, 0));
    }
    assert_eq!(queued, MAX_PENDING_BYTES / 22);
    assert_eq!(s.stats().frames_dropped, 5000 - queued as u64);
    s.consume_output(usize::MAX);
    s.receive_bytes(b"F\rF\r");
    assert_eq!(s.pending_output(), b"F09\rF00\r");
}

#[test]
fn malformed_lines_get_bel_and_are_counted() {
    let s = adapter_after(b"garbage\rt1239\rt8000\rt1232AA\rT1230\rS9\r\x00\xff\r");
    assert_eq!(s.pending_output(), [0x07; 7]);
    assert_eq!(s.stats().malformed, 7);
    assert_eq!(s.stats().commands, 0);
}

#[test]
fn a_client_opens_the_channel_and_exchanges_frames_with_the_endpoint() {
    let spec = EndpointSpec::Tcp("127.0.0.1:0".into());
    let mut endpoint = SlcanEndpoint::open(&spec).unwrap();
    let address = endpoint.describe().strip_prefix("tcp:").unwrap().to_owned();
    let serve = std::thread::spawn(move || {
        let hb = CanFrame::standard(0x1A1, &[0, 0, 0, 0, 8, 0, 0, 0]).unwrap();
        let mut got = None;
        for _ in 0..5000 {
            if let Some(frame) = endpoint.recv(0).unwrap() {
                got = Some(frame);
            }
            if got.is_some() {
                endpoint.send(&hb, 0).unwrap();
                endpoint.recv(0).unwrap();
                std::thread::sleep(Duration::from_millis(20));
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        (got, endpoint.adapter().stats())
    });
    let mut client =
        SlcanClient::connect(&EndpointSpec::Tcp(address), Duration::from_secs(5)).unwrap();
    let estop = CanFrame::standard(0x1A2, &[]).unwrap();
    client.send(&estop, 0).unwrap();
    let mut heard = None;
    for _ in 0..5000 {
        if let Some(frame) = client.recv(0).unwrap() {
            heard = Some(frame);
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let (got, stats) = serve.join().unwrap();
    assert_eq!(got, Some(estop));
    assert_eq!(heard.map(|f| f.raw_id()), Some(0x1A1));
    assert_eq!((stats.malformed, stats.refused, stats.clients), (0, 0, 1));
    assert_eq!(client.stats().refused, 0);
    let no_one = SlcanClient::connect(
        &EndpointSpec::Tcp("127.0.0.1:1".into()),
        Duration::from_secs(1),
    );
    assert!(no_one.is_err());
}

#[test]
fn timestamps_are_milliseconds_modulo_a_minute() {
    let mut s = adapter_after(b"Z1\rO\r");
    s.consume_output(usize::MAX);
    let f = CanFrame::standard(0x001, &[]).unwrap();
    s.frame_to_client(&f, 61_234_999);
    assert_eq!(s.pending_output(), b"t001004D2\r");
}
