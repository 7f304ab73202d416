//! The `firmware_sim` binary behind its SLCAN endpoint, driven with raw SLCAN lines: malformed
//! lines get BEL, python-can's open sequence opens the channel, every axis sends heartbeats, a
//! wheel axis follows a velocity command in closed loop and stops on Estop. Then the same
//! endpoint on a pseudo-terminal answers like an adapter on a serial port.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

const BEL: u8 = 0x07;

/// Kills the simulator when the test ends, passed or not.
struct Sim(Child);

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `firmware_sim --slcan <spec>` and returns it with the place it printed.
fn start(spec: &str) -> (Sim, String) {
    start_with(spec, &[])
}

/// [`start`] with more arguments.
fn start_with(spec: &str, more: &[&str]) -> (Sim, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_firmware_sim"))
        .args(["--slcan", spec, "--duration-s", "60"])
        .args(more)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("firmware_sim starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let place = line
        .trim()
        .strip_prefix("firmware_sim: SLCAN on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_owned();
    (Sim(child), place)
}

/// Splits what the adapter sends into replies: lines without their CR, and BEL alone.
fn replies<R: Read + Send + 'static>(mut input: R) -> Receiver<Vec<u8>> {
    let (tx, rx) = channel();
    std::thread::spawn(move || {
        let mut line = Vec::new();
        let mut buf = [0u8; 4096];
        while let Ok(n) = input.read(&mut buf) {
            if n == 0 {
                break;
            }
            for &b in &buf[..n] {
                match b {
                    b'\r' => {
                        if tx.send(std::mem::take(&mut line)).is_err() {
                            return;
                        }
                    }
                    BEL => {
                        if tx.send(vec![BEL]).is_err() {
                            return;
                        }
                    }
                    _ => line.push(b),
                }
            }
        }
    });
    rx
}

fn next(rx: &Receiver<Vec<u8>>) -> Vec<u8> {
    rx.recv_timeout(Duration::from_secs(5))
        .expect("a reply within 5 s")
}

/// A `t` line's id and data.
fn parse_t(line: &[u8]) -> Option<(u16, Vec<u8>)> {
    let text = std::str::from_utf8(line).ok()?;
    let rest = text.strip_prefix('t')?;
    let id = u16::from_str_radix(rest.get(..3)?, 16).ok()?;
    let dlc = usize::from_str_radix(rest.get(3..4)?, 16).ok()?;
    let data = (0..dlc)
        .map(|i| u8::from_str_radix(&rest[4 + 2 * i..6 + 2 * i], 16).unwrap())
        .collect();
    Some((id, data))
}

fn t_line(id: u16, data: &[u8]) -> String {
    let hex: String = data.iter().map(|b| format!("{b:02X}")).collect();
    format!("t{id:03X}{}{hex}\r", data.len())
}

#[derive(Default)]
struct Seen {
    heartbeats: Vec<(u8, u32, u8)>,
    estimates: Vec<(u8, f32, f32)>,
    bels: usize,
    acks: usize,
}

impl Seen {
    fn take(&mut self, line: &[u8]) {
        if line == [BEL] {
            self.bels += 1;
        } else if line == b"z" {
            self.acks += 1;
        } else if let Some((id, data)) = parse_t(line) {
            let node = (id >> 5) as u8;
            match id & 0x1F {
                0x01 => self.heartbeats.push((
                    node,
                    u32::from_le_bytes(data[0..4].try_into().unwrap()),
                    data[4],
                )),
                0x09 => self.estimates.push((
                    node,
                    f32::from_le_bytes(data[0..4].try_into().unwrap()),
                    f32::from_le_bytes(data[4..8].try_into().unwrap()),
                )),
                _ => {}
            }
        }
    }
}

/// Reads for `duration`, calling `every_20ms` on that period (setpoints well inside a 100 ms
/// watchdog, were one configured).
fn watch(
    rx: &Receiver<Vec<u8>>,
    seen: &mut Seen,
    duration: Duration,
    mut every_20ms: impl FnMut(),
) {
    let end = Instant::now() + duration;
    let mut next_tick = Instant::now();
    while Instant::now() < end {
        if Instant::now() >= next_tick {
            every_20ms();
            next_tick += Duration::from_millis(20);
        }
        if let Ok(line) = rx.recv_timeout(Duration::from_millis(2)) {
            seen.take(&line);
        }
    }
}

#[test]
fn raw_slcan_lines_drive_a_wheel_axis_over_tcp() {
    let (_sim, place) = start("tcp:127.0.0.1:0");
    let address = place.strip_prefix("tcp:").expect("a tcp: address");
    let mut stream = TcpStream::connect(address).unwrap();
    stream.set_nodelay(true).unwrap();
    let rx = replies(stream.try_clone().unwrap());

    // Closed channel: nothing flows, so every reply is the answer to one line, in order.
    let malformed: [&[u8]; 9] = [
        b"garbage\r",
        b"t1239\r",   // DLC over 8
        b"t8000\r",   // 11-bit id over 0x7FF
        b"t1232AA\r", // 2 bytes announced, 1 sent
        b"t1G20\r",   // bad hex
        b"T1230\r",   // a 3-digit id on an extended frame
        b"S9\r",      // no such bit rate
        b"d1A20\r",   // CAN FD: unsupported
        &[b'A'; 100], // overlong (ended by the CR below)
    ];
    for line in malformed {
        stream.write_all(line).unwrap();
    }
    stream.write_all(b"\r").unwrap();
    for line in malformed {
        assert_eq!(next(&rx), [BEL], "{:?}", String::from_utf8_lossy(line));
    }
    // A frame on a closed channel is refused; V and N answer.
    stream.write_all(b"t1A20\rV\rN\r").unwrap();
    assert_eq!(next(&rx), [BEL]);
    assert_eq!(next(&rx), b"V0100");
    assert_eq!(next(&rx), b"NWLSM");
    // python-can's open sequence with bitrate=1000000: C, S8, an empty line, O, O again.
    stream.write_all(b"C\rS8\r\rO\rO\r").unwrap();
    for _ in 0..4 {
        assert_eq!(next(&rx), b"");
    }

    // Every axis sends heartbeats (every 100 ms): all idle, no errors.
    let mut seen = Seen::default();
    watch(&rx, &mut seen, Duration::from_millis(400), || {});
    for node in 1..=16u8 {
        assert!(
            seen.heartbeats
                .iter()
                .any(|&(n, error, state)| n == node && error == 0 && state == 1),
            "no idle heartbeat from node {node}: {:?}",
            seen.heartbeats
        );
    }
    assert_eq!(seen.bels, 0);

    // Node 14 (front-right wheel): velocity control, closed loop, 3 turns/s every 20 ms.
    let node: u16 = 14;
    let send = |s: &mut TcpStream, cmd: u16, data: &[u8]| {
        s.write_all(t_line(node << 5 | cmd, data).as_bytes())
            .unwrap()
    };
    let mut mode = 2u32.to_le_bytes().to_vec();
    mode.extend(1u32.to_le_bytes());
    send(&mut stream, 0x0B, &mode);
    let mut state = 8u32.to_le_bytes().to_vec();
    state.extend([0; 4]);
    send(&mut stream, 0x07, &state);
    let mut vel = 3.0f32.to_le_bytes().to_vec();
    vel.extend(0.0f32.to_le_bytes());
    let mut seen = Seen::default();
    let mut writer = stream.try_clone().unwrap();
    watch(&rx, &mut seen, Duration::from_millis(1200), || {
        send(&mut writer, 0x0D, &vel)
    });
    // A malformed line while frames flow still gets its BEL.
    stream.write_all(b"t0000000\r").unwrap();
    assert!(
        seen.heartbeats
            .iter()
            .any(|&(n, error, state)| n == 14 && error == 0 && state == 8),
        "node 14 never in closed loop: {:?}",
        seen.heartbeats
    );
    let wheel: Vec<(f32, f32)> = seen
        .estimates
        .iter()
        .filter(|e| e.0 == 14)
        .map(|e| (e.1, e.2))
        .collect();
    assert!(wheel.len() > 50, "{} estimates", wheel.len());
    let (first, last) = (wheel[0], wheel[wheel.len() - 1]);
    assert!(
        (last.1 - 3.0).abs() < 0.05 && first.1 < last.1,
        "velocity {} -> {}",
        first.1,
        last.1
    );
    assert!(last.0 - first.0 > 1.5, "position {} -> {}", first.0, last.0);
    assert!(seen.acks >= 50, "{} transmit acknowledgements", seen.acks);

    // Estop: idle with ESTOP_REQUESTED, the wheel spins down; the BEL arrived too.
    send(&mut stream, 0x02, &[]);
    let mut after = Seen::default();
    watch(&rx, &mut after, Duration::from_millis(800), || {});
    assert_eq!(seen.bels + after.bels, 1);
    let &(_, error, state) = after
        .heartbeats
        .iter()
        .rev()
        .find(|h| h.0 == 14)
        .expect("a heartbeat after Estop");
    assert_eq!((error & 0x4000, state), (0x4000, 1));
    let &(_, _, v) = after.estimates.iter().rev().find(|e| e.0 == 14).unwrap();
    assert!(v.abs() < 0.01, "still turning at {v} turns/s");
    // The other wheels never moved.
    assert!(after
        .estimates
        .iter()
        .filter(|e| (13..=16).contains(&e.0) && e.0 != 14)
        .all(|e| e.2 == 0.0));
}

#[test]
fn a_second_client_is_refused_and_the_next_one_starts_closed() {
    let (_sim, place) = start("tcp:127.0.0.1:0");
    let address = place.strip_prefix("tcp:").unwrap();
    let mut first = TcpStream::connect(address).unwrap();
    let rx = replies(first.try_clone().unwrap());
    first.write_all(b"O\r").unwrap();
    assert_eq!(next(&rx), b"");
    let second = TcpStream::connect(address).unwrap();
    let rx2 = replies(second);
    assert_eq!(
        rx2.recv_timeout(Duration::from_secs(5)),
        Err(RecvTimeoutError::Disconnected),
        "the second connection is closed without a word"
    );
    drop(rx);
    drop(first);
    // The next client finds the channel closed: a frame is refused until it opens.
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut third = loop {
        let mut s = TcpStream::connect(address).unwrap();
        s.write_all(b"t1A20\r").unwrap();
        let rx3 = replies(s.try_clone().unwrap());
        match rx3.recv_timeout(Duration::from_millis(500)) {
            Ok(reply) => {
                assert_eq!(reply, [BEL]);
                break (s, rx3);
            }
            // Still refused as a second client: the first has not been noticed gone yet.
            Err(_) => assert!(
                Instant::now() < deadline,
                "no client accepted after the first"
            ),
        }
    };
    third.0.write_all(b"O\rt1A20\r").unwrap();
    assert_eq!(next(&third.1), b"");
    assert_eq!(next(&third.1), b"z");
}

#[cfg(unix)]
#[test]
fn the_pty_endpoint_answers_like_a_serial_adapter() {
    let (_sim, path) = start("pty");
    assert!(path.starts_with("/dev/"), "{path}");
    let mut tty = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&path)
        .unwrap();
    let rx = replies(tty.try_clone().unwrap());
    tty.write_all(b"V\rbad\rO\r").unwrap();
    assert_eq!(next(&rx), b"V0100");
    assert_eq!(next(&rx), [BEL]);
    assert_eq!(next(&rx), b"");
    let mut seen = Seen::default();
    watch(&rx, &mut seen, Duration::from_millis(300), || {});
    assert!(
        (1..=16u8).all(|n| seen.heartbeats.iter().any(|h| h.0 == n)),
        "{:?}",
        seen.heartbeats
    );
}

#[test]
fn the_axes_are_the_robot_descriptions() {
    let strider = concat!(env!("CARGO_MANIFEST_DIR"), "/../robots/strider.toml");
    let (_sim, place) = start_with("tcp:127.0.0.1:0", &["--robot", strider]);
    let address = place.strip_prefix("tcp:").expect("a tcp: address");
    let mut stream = TcpStream::connect(address).unwrap();
    stream.set_nodelay(true).unwrap();
    let rx = replies(stream.try_clone().unwrap());
    stream.write_all(b"S8\rO\r").unwrap();
    for _ in 0..2 {
        assert_eq!(next(&rx), b"");
    }
    let mut seen = Seen::default();
    watch(&rx, &mut seen, Duration::from_millis(400), || {});
    // Its 16 axes on nodes 21 to 36, none on the shipped robot's 1 to 16.
    for node in 21..=36u8 {
        assert!(
            seen.heartbeats.iter().any(|h| h.0 == node),
            "no heartbeat from node {node}: {:?}",
            seen.heartbeats
        );
    }
    assert!(seen.heartbeats.iter().all(|h| (21..=36).contains(&h.0)));
}

#[test]
fn a_bad_robot_description_is_refused_naming_the_key() {
    let dir = std::env::temp_dir().join(format!("firmware-sim-robot-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    let shipped = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../robots/wheelleg.toml"
    ))
    .unwrap();
    std::fs::write(&bad, shipped.replacen("node_id = 5,", "node_id = 4,", 1)).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_firmware_sim"))
        .args(["--slcan", "tcp:127.0.0.1:0", "--duration-s", "1", "--robot"])
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("can.axes.front_right_knee.node_id"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
