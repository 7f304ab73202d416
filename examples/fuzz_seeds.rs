//! Writes the fuzz targets' seed corpora (fuzz/seeds/TARGET/) from files the project really
//! makes: weights files from the trainer's quantizer (the default network with random weights,
//! as `trainer/examples/random_policy.rs` writes it, and small networks), scenario files as
//! `wheelleg generate` writes them, checkpoints of small networks as the trainer writes them, and
//! the bus traffic of the closed loop as `firmware_sim/examples/closed_loop_log.rs` logs it.
//!
//! `cargo run --release --example fuzz_seeds -- fuzz/seeds`
//!
//! The CAN seeds are in the CAN target's record format (fuzz/src/lib.rs, `frame_records`):
//! 14 bytes per frame, byte 0 = extended | remote << 1 | milliseconds-to-next << 2, bytes 1..5
//! the id (LE), byte 5 the DLC, bytes 6..14 the data.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing)]

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use wheelleg_firmware_sim::candump::{parse_log, CandumpWriter, DEFAULT_EPOCH_US};
use wheelleg_firmware_sim::rig::{Rig, RigConfig};
use wheelleg_runtime::action::{Action, Step};
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::model::format::FORMAT_VERSION;
use wheelleg_runtime::robot::{LegId, WHEELLEG};
use wheelleg_sim::env::{Env, EnvConfig, Observation};
use wheelleg_sim::generate::{generate, SceneKind};
use wheelleg_trainer::checkpoint::{Checkpoint, NetworkRecord};
use wheelleg_trainer::network_f32::{Architecture, ConvSpec, NetworkF32};
use wheelleg_trainer::ppo::Adam;
use wheelleg_trainer::quantize::{
    quantize_for_version, Calibration, QuantizedNetwork, RangeMethod,
};
use wheelleg_trainer::vec_env::EnvSnapshot;

/// Frames per CAN seed: small inputs mutate faster; a seed still spans start-up or a step.
const FRAMES_PER_SEED: usize = 300;

fn write(dir: &Path, target: &str, name: &str, bytes: &[u8]) {
    let dir = dir.join(target);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(name), bytes).unwrap();
    println!("{target}/{name}: {} bytes", bytes.len());
}

/// Small networks of the supported family: tiny maps, zero to two convs, a hidden layer or none.
fn small_architectures() -> Vec<Architecture> {
    let conv = |in_channels, out_channels, kernel, stride, padding| ConvSpec {
        in_channels,
        out_channels,
        kernel,
        stride,
        padding,
    };
    vec![
        Architecture {
            height_rows: 4,
            height_cols: 4,
            state_len: 4,
            convs: vec![],
            hidden: vec![8],
            value_head: true,
        },
        Architecture {
            height_rows: 6,
            height_cols: 5,
            state_len: 2,
            convs: vec![conv(1, 3, 3, 2, 1)],
            hidden: vec![],
            value_head: false,
        },
        Architecture {
            height_rows: 8,
            height_cols: 8,
            state_len: 4,
            convs: vec![conv(1, 4, 3, 2, 1), conv(4, 4, 2, 1, 0)],
            hidden: vec![6, 5],
            value_head: true,
        },
    ]
}

/// Heights and state in metres for an architecture: a box on flat ground.
fn observation(arch: &Architecture) -> (Vec<f32>, Vec<f32>) {
    let mut height = vec![0.0f32; arch.height_rows * arch.height_cols];
    for (i, h) in height.iter_mut().enumerate() {
        if i % arch.height_cols >= arch.height_cols / 2 && i / arch.height_cols < 2 {
            *h = 0.2;
        }
    }
    let state = [0.12, 0.36, 2.0, 0.5, 0.1, -0.1];
    (height, state[..arch.state_len].to_vec())
}

/// The network quantized for the current weights format version.
fn quantized(network: &NetworkF32, observations: &[(Vec<f32>, Vec<f32>)]) -> QuantizedNetwork {
    quantized_version(network, observations, FORMAT_VERSION)
}

/// The network quantized for a weights format version (1: int8 state and logits, 2: int16).
fn quantized_version(
    network: &NetworkF32,
    observations: &[(Vec<f32>, Vec<f32>)],
    version: u16,
) -> QuantizedNetwork {
    let calibration = Calibration::from_observations(
        network,
        observations
            .iter()
            .map(|(h, s)| (h.as_slice(), s.as_slice())),
    );
    quantize_for_version(network, &calibration, RangeMethod::MinMax, version).unwrap()
}

fn weights_seeds(out: &Path) {
    // The default network as trainer/examples/random_policy.rs writes it.
    let default = Architecture::default_policy();
    let network = NetworkF32::random(&default, &mut ChaCha8Rng::seed_from_u64(7));
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let observations: Vec<(Vec<f32>, Vec<f32>)> = (0..4)
        .map(|i| {
            let scene = generate(
                wheelleg_sim::generate::SceneRobot::shipped(),
                SceneKind::Complex,
                &mut rng,
                format!("calibration-{i}"),
            );
            let mut o = Observation::default();
            Env::new(&scene, EnvConfig::default())
                .unwrap()
                .observe(&mut o);
            (o.height_map.to_vec(), o.state.to_vec())
        })
        .collect();
    let q = quantized(&network, &observations);
    write(out, "weights_file", "default.wlw", &q.to_bytes().unwrap());
    // The runtime still reads version 1 files (int8 state and logits): keep that path fuzzed
    // too.
    let old = quantized_version(&network, &observations, 1);
    write(
        out,
        "weights_file",
        "default-v1.wlw",
        &old.to_bytes().unwrap(),
    );
    for (i, arch) in small_architectures().iter().enumerate() {
        let network = NetworkF32::random(arch, &mut ChaCha8Rng::seed_from_u64(i as u64));
        let q = quantized(&network, &[observation(arch)]);
        let name = format!("small-{i}");
        write(
            out,
            "weights_file",
            &format!("{name}.wlw"),
            &q.to_bytes().unwrap(),
        );
        write(
            out,
            "weights_payload",
            &format!("{name}.payload"),
            &q.payload_bytes().unwrap(),
        );
    }
}

fn scenario_seeds(out: &Path) {
    for kind in SceneKind::ALL {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let scenes: Vec<_> = (0..2)
            .map(|i| {
                generate(
                    wheelleg_sim::generate::SceneRobot::shipped(),
                    kind,
                    &mut rng,
                    format!("{}-{i}", kind.name()),
                )
            })
            .collect();
        let json = wheelleg_sim::scenario_file::to_json(
            &scenes,
            &wheelleg_sim::robot::SimulatedRobot::SHIPPED,
        );
        write(
            out,
            "scenario_json",
            &format!("{}.json", kind.name()),
            json.as_bytes(),
        );
    }
}

fn checkpoint_seeds(out: &Path) {
    for (i, arch) in small_architectures().iter().enumerate() {
        let network = NetworkF32::random(arch, &mut ChaCha8Rng::seed_from_u64(i as u64));
        let scene = generate(
            wheelleg_sim::generate::SceneRobot::shipped(),
            SceneKind::Complex,
            &mut ChaCha8Rng::seed_from_u64(i as u64),
            format!("complex-e0-{i}"),
        );
        let envs = (0..i)
            .map(|e| EnvSnapshot {
                scene_rng_word_pos: 1234 * e as u128,
                scenario_json: wheelleg_sim::scenario_file::to_json(
                    std::slice::from_ref(&scene),
                    &wheelleg_sim::robot::SimulatedRobot::SHIPPED,
                ),
                actions: vec![121, 40, 202][..e].to_vec(),
                episodes_started: e as u64,
            })
            .collect();
        let checkpoint = Checkpoint {
            kind: "baseline".into(),
            config_toml: "[run]\nscene_kind = \"straight\"\n".into(),
            seed: i as u64,
            iteration: 3 + i as u64,
            env_steps: 3000,
            adam: Adam::new(&network),
            network: NetworkRecord::from_network(&network),
            sampler_word_pos: 98_765,
            envs,
            elapsed_s: 12.5,
        };
        let bytes = checkpoint.to_bytes().unwrap();
        let name = format!("small-{i}");
        write(out, "checkpoint_file", &format!("{name}.ckpt"), &bytes);
        write(
            out,
            "checkpoint_payload",
            &format!("{name}.payload"),
            &bytes[24..],
        );
    }
}

#[derive(Clone, Default)]
struct SharedLog(Arc<Mutex<Vec<u8>>>);

impl Write for SharedLog {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// One `candump -L` frame (`ID#DATA`, `ID#R` or `ID#Rn`, ids of 3 or 8 hex digits) as a CAN
/// target record; parsed from the text so that this stays independent of the frame type's trait.
fn frame_record(advance_ms: u64, candump_frame: &str) -> [u8; 14] {
    let (id, rest) = candump_frame.split_once('#').unwrap();
    let extended = id.len() == 8;
    let raw = u32::from_str_radix(id, 16).unwrap();
    let mut record = [0u8; 14];
    let remote = rest.starts_with('R');
    record[0] = u8::from(extended) | (u8::from(remote) << 1) | ((advance_ms.min(31) as u8) << 2);
    record[1..5].copy_from_slice(&raw.to_le_bytes());
    if remote {
        record[5] = rest[1..].parse().unwrap_or(0);
    } else {
        let data: Vec<u8> = (0..rest.len() / 2)
            .map(|i| u8::from_str_radix(&rest[2 * i..2 * i + 2], 16).unwrap())
            .collect();
        record[5] = data.len() as u8;
        record[6..6 + data.len()].copy_from_slice(&data);
    }
    record
}

/// The closed loop's bus traffic: start-up, a step, a node going silent, Estop, recovery.
fn can_seeds(out: &Path) {
    let legs = LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    };
    let mut rig = Rig::in_process(
        &wheelleg_runtime::robot::Robot::WHEELLEG,
        RigConfig::default(),
        legs,
    )
    .unwrap();
    let log = SharedLog::default();
    rig.log_to(CandumpWriter::new(
        Box::new(log.clone()),
        "can0",
        DEFAULT_EPOCH_US,
    ));
    rig.start_up().unwrap();
    rig.step(Action {
        move_x: Step::Plus,
        track: Step::Plus,
        ..Action::IDLE
    })
    .unwrap();
    let silent = Axis::Wheel(LegId::RearLeft);
    rig.firmware_mut()
        .axis_mut(silent)
        .unwrap()
        .set_silent(true);
    rig.step(Action {
        yaw: Step::Plus,
        ..Action::IDLE
    })
    .unwrap();
    rig.estop().unwrap();
    rig.firmware_mut()
        .axis_mut(silent)
        .unwrap()
        .set_silent(false);
    rig.recover().unwrap();
    rig.take_log().unwrap();
    let text = String::from_utf8(log.0.lock().unwrap().clone()).unwrap();
    let entries = parse_log(&text).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), entries.len());
    let records: Vec<[u8; 14]> = entries
        .iter()
        .zip(&lines)
        .enumerate()
        .map(|(i, (entry, line))| {
            let next = entries.get(i + 1).map_or(entry.time_us, |n| n.time_us);
            let frame = line.rsplit(' ').next().unwrap();
            frame_record((next - entry.time_us) / 1_000, frame)
        })
        .collect();
    // Seeds spread over the whole exchange (start-up, motion, silence, Estop, recovery), not
    // every chunk: the traffic repeats itself from tick to tick.
    let chunks: Vec<&[[u8; 14]]> = records.chunks(FRAMES_PER_SEED).collect();
    let picks = 6.min(chunks.len());
    for k in 0..picks {
        let chunk = chunks[k * chunks.len() / picks];
        write(
            out,
            "can_frames",
            &format!("closed-loop-{k}.bin"),
            &chunk.concat(),
        );
    }
}

fn main() {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "fuzz/seeds".into()),
    );
    weights_seeds(&out);
    scenario_seeds(&out);
    checkpoint_seeds(&out);
    can_seeds(&out);
    robot_seeds(&out);
}

/// The shipped and the second robot's descriptions as committed, and each as the URDF that
/// `wheelleg robot urdf` writes.
fn robot_seeds(out: &Path) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for name in ["wheelleg", "strider"] {
        let file = root.join("robots").join(format!("{name}.toml"));
        let description = wheelleg_robot::RobotDescription::load(&file).expect("a committed robot");
        write(
            out,
            "robot_description",
            &format!("{name}.toml"),
            &std::fs::read(&file).expect("readable"),
        );
        write(
            out,
            "robot_urdf",
            &format!("{name}.urdf"),
            wheelleg_robot::urdf::export(&description).as_bytes(),
        );
    }
}
