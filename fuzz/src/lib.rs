//! What every fuzz target checks, kept apart from the `fuzz_target!` shells so that a crash
//! input can be replayed by hand (`cargo +nightly fuzz run TARGET artifacts/TARGET/crash-...`)
//! and so the input formats are written down once.
//!
//! Each check feeds bytes nobody vouches for into one of the project's decoders and asserts the
//! decoder's promise: no panic, no hang, no unbounded allocation (libFuzzer's `-rss_limit_mb` and
//! `-timeout` watch those two), and nothing accepted that the rest of the program cannot use.
//! Inputs behind a checksum get a second, structure-aware target that fixes the checksum up, or
//! the fuzzer would never get past it (docs/robustness.md).

use embedded_can::{ExtendedId, Frame, Id, StandardId};
use wheelleg_firmware_sim::bus::{BusError, Transport};
use wheelleg_firmware_sim::firmware::Firmware;
use wheelleg_runtime::can::host::{Commander, FeedbackTracker, TxQueue};
use wheelleg_runtime::can::protocol::{decode, encode};
use wheelleg_runtime::can::{CanFrame, NodeMap};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::model::{DefaultPolicy, LoadError, Model};
use wheelleg_runtime::robot::WHEELLEG;
use wheelleg_trainer::checkpoint::Checkpoint;

/// A weights file (`.wlw`): the loader refuses it with a typed error or accepts a model that
/// then runs on inputs of its own shape, whatever their values.
pub fn check_weights_file(bytes: &[u8]) {
    let parsed = Model::parse(bytes);
    match DefaultPolicy::from_bytes(bytes) {
        Ok(policy) => {
            assert!(parsed.is_ok(), "the policy accepts what the model refuses");
            let model = policy.model();
            let cells = usize::from(model.input.rows) * usize::from(model.input.cols);
            let features = model.state.len();
            // Flat ground at rest, and the most extreme readings the sensors can produce.
            for (height, state) in [(0i16, 0i32), (i16::MAX, i32::MIN), (i16::MIN, i32::MAX)] {
                let heights = vec![height; cells];
                let states = vec![state; features];
                let outputs = policy
                    .evaluate(&heights, &states)
                    .unwrap_or_else(|e| panic!("an accepted model fails inference: {e:?}"));
                let _ = outputs.action();
                let _ = outputs.value_f32();
            }
        }
        Err(LoadError::ExceedsCapacity { .. }) => {}
        Err(error) => assert_eq!(parsed.err(), Some(error), "model and policy disagree"),
    }
}

/// The `.wlw` payload alone, wrapped in a valid envelope (magic, version, CRC) by the trainer's
/// own writer, so mutations reach the layer records instead of failing the checksum.
pub fn check_weights_payload(payload: &[u8]) {
    let version = wheelleg_runtime::model::format::FORMAT_VERSION;
    if let Ok(file) = wheelleg_trainer::quantize::file_bytes::envelope_bytes(version, payload) {
        check_weights_file(&file);
    }
}

/// Bytes per frame record of the CAN target.
pub const FRAME_RECORD_LEN: usize = 14;

/// The CAN target's input: fixed 14-byte records (fixed so that mutations keep frames aligned).
///
/// | byte | meaning                                                                      |
/// |------|------------------------------------------------------------------------------|
/// | 0    | bit 0 extended id, bit 1 remote frame, bits 2..6: milliseconds to let pass after it |
/// | 1..5 | id, little-endian (masked to 11 or 29 bits)                                  |
/// | 5    | data length code (mod 9)                                                     |
/// | 6..14| data bytes (the first `dlc` are used)                                        |
///
/// A trailing partial record is ignored.
pub fn frame_records(data: &[u8]) -> impl Iterator<Item = (u64, CanFrame)> + '_ {
    data.chunks_exact(FRAME_RECORD_LEN).filter_map(|record| {
        let flags = record[0];
        let raw = u32::from_le_bytes([record[1], record[2], record[3], record[4]]);
        let dlc = usize::from(record[5] % 9);
        let id: Id = if flags & 1 != 0 {
            ExtendedId::new(raw & 0x1FFF_FFFF)?.into()
        } else {
            StandardId::new((raw & 0x7FF) as u16)?.into()
        };
        let frame = if flags & 2 != 0 {
            CanFrame::new_remote(id, dlc)?
        } else {
            CanFrame::new(id, &record[6..6 + dlc])?
        };
        Some((u64::from((flags >> 2) & 0x1F), frame))
    })
}

/// The inverse of [`frame_records`] for one frame (used to turn bus logs into seeds).
pub fn frame_record(advance_ms: u8, frame: &CanFrame) -> [u8; FRAME_RECORD_LEN] {
    let mut record = [0u8; FRAME_RECORD_LEN];
    record[0] = u8::from(frame.is_extended())
        | (u8::from(frame.is_remote_frame()) << 1)
        | ((advance_ms.min(0x1F)) << 2);
    record[1..5].copy_from_slice(&frame.raw_id().to_le_bytes());
    record[5] = frame.dlc() as u8;
    let data = frame.data();
    record[6..6 + data.len()].copy_from_slice(data);
    record
}

/// Frames the simulated axes sent during one physics step, handed back to the controller.
#[derive(Default)]
struct Loopback(Vec<CanFrame>);

impl Transport for Loopback {
    fn send(&mut self, frame: &CanFrame, _now_us: u64) -> Result<(), BusError> {
        self.0.push(*frame);
        Ok(())
    }

    fn recv(&mut self, _now_us: u64) -> Result<Option<CanFrame>, BusError> {
        Ok(None)
    }
}

/// A stream of arbitrary frames on the robot's bus, seen by both ends: the runtime's codec and
/// feedback tracker (the controller's state machine) and the simulated ODrive axes (theirs).
/// Time passes between frames, so watchdogs, timeouts and motor physics run too.
pub fn check_can_frames(data: &[u8]) {
    let map = NodeMap::NOMINAL;
    let start = LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    };
    let mut tracker = FeedbackTracker::new(map);
    let commander = Commander::new(map);
    let mut firmware = match Firmware::for_robot(&WHEELLEG, &map, start) {
        Ok(firmware) => firmware,
        Err(e) => panic!("the default legs have no IK solution: {e:?}"),
    };
    // Configured as the closed loop configures it, so the watchdog's paths are fuzzed too.
    firmware.set_watchdog_timeout_us(100_000);
    let mut loopback = Loopback::default();
    let mut now_us = 0u64;
    let mut heard = 0u64;
    for (advance_ms, frame) in frame_records(data) {
        // The codec: whatever decodes re-encodes to a frame that decodes to the same message.
        if let Ok((node, message)) = decode(&frame) {
            let again: CanFrame = encode(node, &message)
                .unwrap_or_else(|e| panic!("decoded {message:?} but cannot re-encode: {e:?}"));
            assert_eq!(decode(&again), Ok((node, message)));
        }
        tracker.receive(&frame, now_us);
        firmware.receive(&frame, now_us);
        heard += 1;
        for _ in 0..advance_ms {
            now_us += 1_000;
            if let Err(e) = firmware.run(&mut loopback, now_us, 0.001) {
                panic!("the loopback transport cannot fail: {e}");
            }
            for reply in loopback.0.drain(..) {
                tracker.receive(&reply, now_us);
                heard += 1;
            }
        }
        let stats = tracker.stats();
        assert_eq!(
            u64::from(stats.accepted) + u64::from(stats.malformed) + u64::from(stats.unexpected),
            heard,
            "every frame is counted exactly once"
        );
        for axis in firmware.axes() {
            assert!(
                axis.pos_turns().is_finite() && axis.vel_turns_per_s().is_finite(),
                "a command drove axis {:?} to a non-finite state",
                axis.node()
            );
        }
        // Whatever the bus said, the controller can still judge it and stop the robot.
        let _ = tracker.health(now_us, 50_000);
        let mut queue: TxQueue<CanFrame, 32> = TxQueue::new();
        if let Err(e) = commander.queue_safe_stop(&mut queue, &tracker) {
            panic!("safe stop cannot be queued after {heard} frames: {e:?}");
        }
        let _ = tracker.leg_config(&WHEELLEG);
        let _ = tracker.wheel_speeds();
    }
}

/// Bytes from an SLCAN client (a USB-CAN adapter's serial line), in two places: the runtime's
/// line decoder, and the simulated adapter (`firmware_sim::slcan::SlcanAdapter`) in front of the
/// 16 simulated axes, with a millisecond of physics after every line.
///
/// Checks: every error and command is counted once; whatever decodes re-encodes to a line that
/// decodes to the same command; the adapter answers every malformed or refused line with
/// exactly one BEL; what it sends back is printable ASCII, CR and BEL only, within its output
/// bound; no frame from the client drives a motor to a non-finite state.
pub fn check_slcan_lines(data: &[u8]) {
    use wheelleg_firmware_sim::slcan::{SlcanAdapter, MAX_PENDING_BYTES};
    use wheelleg_runtime::can::slcan::{encode_command, Decoder, BEL, CR, LINE_CAPACITY};

    let mut decoder = Decoder::new();
    let (mut commands, mut errors) = (0u32, 0u32);
    for &byte in data {
        match decoder.feed(byte) {
            Ok(None) => {}
            Ok(Some(command)) => {
                commands += 1;
                let line = encode_command(&command);
                assert!(line.as_bytes().len() <= LINE_CAPACITY);
                let mut again = Decoder::new();
                let mut back = None;
                for &b in line.as_bytes() {
                    match again.feed(b) {
                        Ok(None) => {}
                        Ok(Some(c)) => back = Some(c),
                        Err(e) => panic!("{command:?} re-encodes to {line:?}, refused: {e}"),
                    }
                }
                assert_eq!(back, Some(command), "{line:?}");
            }
            Err(_) => errors += 1,
        }
    }
    let stats = decoder.stats();
    assert_eq!((stats.commands, stats.errors), (commands, errors));

    let map = NodeMap::NOMINAL;
    let start = LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    };
    let mut firmware = match Firmware::for_robot(&WHEELLEG, &map, start) {
        Ok(firmware) => firmware,
        Err(e) => panic!("the default legs have no IK solution: {e:?}"),
    };
    let mut adapter = SlcanAdapter::new();
    let mut loopback = Loopback::default();
    let mut sent = Vec::new();
    let mut now_us = 0u64;
    for line in data.split_inclusive(|&b| b == CR) {
        adapter.receive_bytes(line);
        while let Some(frame) = adapter.next_frame() {
            firmware.receive(&frame, now_us);
        }
        now_us += 1_000;
        if let Err(e) = firmware.run(&mut loopback, now_us, 0.001) {
            panic!("the loopback transport cannot fail: {e}");
        }
        for frame in loopback.0.drain(..) {
            adapter.frame_to_client(&frame, now_us);
        }
        let pending = adapter.pending_output();
        assert!(
            pending.len() <= MAX_PENDING_BYTES + data.len(),
            "output unbounded"
        );
        sent.extend_from_slice(pending);
        let n = pending.len();
        adapter.consume_output(n);
    }
    assert!(
        sent.iter()
            .all(|&b| b == CR || b == BEL || b.is_ascii_graphic()),
        "the adapter sent a byte outside printable ASCII, CR and BEL"
    );
    let s = adapter.stats();
    let bels = sent.iter().filter(|&&b| b == BEL).count() as u64;
    assert_eq!(
        bels,
        s.malformed + s.refused,
        "one BEL per malformed or refused line"
    );
    assert_eq!(
        s.malformed,
        u64::from(errors),
        "adapter and decoder disagree"
    );
    for axis in firmware.axes() {
        assert!(
            axis.pos_turns().is_finite() && axis.vel_turns_per_s().is_finite(),
            "an SLCAN frame drove axis {:?} to a non-finite state",
            axis.node()
        );
    }
}

/// Scenario JSON: refused with an error, or accepted as scenarios that write back to a file
/// which reads again to the same scenarios (what `wheelleg generate` writes, `plan` reads).
pub fn check_scenario_json(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    let Ok(scenarios) = wheelleg_sim::scenario_file::parse(text, &wheelleg_sim::robot::SimulatedRobot::SHIPPED) else {
        return;
    };
    let written = wheelleg_sim::scenario_file::to_json(&scenarios, &wheelleg_sim::robot::SimulatedRobot::SHIPPED);
    let reread = wheelleg_sim::scenario_file::parse(&written, &wheelleg_sim::robot::SimulatedRobot::SHIPPED)
        .unwrap_or_else(|e| panic!("a written scenario file does not read back: {e}\n{written}"));
    assert_eq!(
        wheelleg_sim::scenario_file::to_json(&reread, &wheelleg_sim::robot::SimulatedRobot::SHIPPED),
        written,
        "writing is not stable after one round trip"
    );
    // An accepted scenario makes a world the simulator can start (first one only: speed).
    if let Some(scenario) = scenarios.first() {
        let env = wheelleg_sim::env::Env::new(scenario, wheelleg_sim::env::EnvConfig::default());
        assert!(
            env.is_ok(),
            "accepted scenario refused by Env: {:?}",
            env.err()
        );
    }
}

/// A checkpoint file: refused with a message, or accepted as a checkpoint whose network
/// rebuilds and which writes back to bytes that load again to the same bytes.
pub fn check_checkpoint_file(bytes: &[u8]) {
    let Ok(checkpoint) = Checkpoint::from_bytes(bytes) else {
        return;
    };
    if let Err(e) = checkpoint.network.to_network() {
        panic!("an accepted checkpoint's network does not rebuild: {e}");
    }
    let written = checkpoint
        .to_bytes()
        .unwrap_or_else(|e| panic!("an accepted checkpoint does not encode: {e}"));
    let reread = Checkpoint::from_bytes(&written)
        .unwrap_or_else(|e| panic!("a written checkpoint does not load: {e}"));
    assert_eq!(reread.to_bytes().ok(), Some(written));
}

/// FNV-1a 64, the checkpoint header's checksum (trainer/src/checkpoint.rs).
pub fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// The checkpoint payload (postcard) alone, given a valid header, so mutations reach the
/// decoder and the validation behind the checksum.
pub fn check_checkpoint_payload(payload: &[u8]) {
    let mut file = Vec::with_capacity(24 + payload.len());
    file.extend_from_slice(b"WLCKPT01");
    file.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    file.extend_from_slice(&fnv1a(payload).to_le_bytes());
    file.extend_from_slice(payload);
    check_checkpoint_file(&file);
}

/// Recomputes every CRC of a trajectory batch file in place, as far as its lengths can be
/// followed (layout: trainer/src/trajectory/batch_file/mod.rs), so that mutations reach the postcard
/// header and chunks instead of failing the first checksum.
pub fn fix_batch_crcs(bytes: &mut [u8]) {
    use wheelleg_trainer::trajectory::batch_file::crc32;
    let u32_at = |b: &[u8], at: usize| -> Option<usize> {
        Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?) as usize)
    };
    let Some(header_len) = u32_at(bytes, 12) else {
        return;
    };
    let Some(header_end) = 20usize
        .checked_add(header_len)
        .filter(|&e| e <= bytes.len())
    else {
        return;
    };
    let crc = crc32(&bytes[20..header_end]);
    bytes[16..20].copy_from_slice(&crc.to_le_bytes());
    let mut at = header_end;
    while let Some(len) = u32_at(bytes, at) {
        let start = at + 8;
        let Some(end) = start.checked_add(len).filter(|&e| e <= bytes.len()) else {
            return;
        };
        let crc = crc32(&bytes[start..end]);
        bytes[at + 4..at + 8].copy_from_slice(&crc.to_le_bytes());
        at = end;
    }
}

/// A trajectory batch file, checksums fixed up: refused with an error, or accepted as a batch
/// whose every trajectory can be rebuilt.
pub fn check_trajectory_batch(data: &[u8]) {
    use wheelleg_trainer::trajectory::batch_file::TrajectoryBatch;
    let mut bytes = data.to_vec();
    fix_batch_crcs(&mut bytes);
    let Ok(batch) = TrajectoryBatch::from_bytes(&bytes) else {
        return;
    };
    for index in 0..batch.len().min(64) {
        let _ = batch.trajectory(index);
    }
    let _ = batch.counts_by_behaviour();
}

/// Robot description TOML: refused with an error naming a key, or accepted as a robot the
/// runtime can drive (its default pose has a leg solution, its node map is the map it stores)
/// whose written file reads back to the same description.
pub fn check_robot_description(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    let description = match wheelleg_robot::RobotDescription::from_toml(text) {
        Ok(description) => description,
        Err(error) => {
            assert!(!error.to_string().is_empty());
            return;
        }
    };
    assert_eq!(description.robot.geometry.check(), Ok(()));
    let written = description.to_toml();
    let reread = wheelleg_robot::RobotDescription::from_toml(&written)
        .unwrap_or_else(|e| panic!("a written description does not read back: {e}\n{written}"));
    assert_eq!(reread, description);
}

/// URDF text: refused with an error, or imported as a checked description whose exported
/// URDF imports again to the same description.
pub fn check_robot_urdf(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    let Ok(description) = wheelleg_robot::urdf::import(text) else {
        return;
    };
    let exported = wheelleg_robot::urdf::export(&description);
    let again = wheelleg_robot::urdf::import(&exported)
        .unwrap_or_else(|e| panic!("an exported URDF does not import: {e}\n{exported}"));
    assert_eq!(again, description);
}
