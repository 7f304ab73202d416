//! The loader answers every bad file with the right typed error and never panics: the shipped
//! weights file, edits of it, and synthetic files of other architectures written by the tests'
//! own writer of the format records.
#![allow(clippy::unwrap_used, clippy::indexing_slicing, clippy::expect_used)]

mod common;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::can::node_map::AXIS_COUNT;
use wheelleg_runtime::can::{NodeId, NodeMap};
use wheelleg_runtime::model::format::{RobotRecord, FORMAT_VERSION, MAGIC, OLDEST_FORMAT_VERSION};
use wheelleg_runtime::model::load::{Model, TrainedFor, MAX_CONV_LAYERS};
use wheelleg_runtime::model::{Capacity, DefaultPolicy, LayerRef, LoadError, Policy};
use wheelleg_runtime::robot::Robot;

use common::*;

fn default_bytes() -> Vec<u8> {
    shipped_bytes()
}

/// The tests' writer reproduces the shipped file byte for byte, so that its edits below differ
/// from a real file only where they are meant to.
#[test]
fn the_tests_writer_reproduces_the_shipped_file() {
    let bytes = default_bytes();
    let file = WeightsFile::parse(&bytes);
    assert_eq!(file.to_bytes(), bytes);
    // The shipped file predates the robot record: version 2, trained for the shipped robot.
    assert_eq!(file.version, 2);
    assert_eq!(
        file.architecture().convs.len(),
        3,
        "the default architecture"
    );
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let synthetic = WeightsFile::synthetic(&mut rng, &file.architecture());
    assert_eq!(WeightsFile::parse(&synthetic.to_bytes()), synthetic);
    assert!(DefaultPolicy::from_bytes(&synthetic.to_bytes()).is_ok());
}

#[test]
fn a_valid_file_loads_and_every_prefix_is_truncated() {
    let bytes = default_bytes();
    assert!(DefaultPolicy::from_bytes(&bytes).is_ok());
    for len in 0..bytes.len() {
        assert_eq!(
            Model::parse(&bytes[..len]).err(),
            Some(LoadError::Truncated),
            "prefix of {len} bytes"
        );
    }
}

#[test]
fn magic_version_checksum_and_trailing_bytes_are_checked() {
    let bytes = default_bytes();
    assert_eq!(&bytes[..4], &MAGIC);

    let mut wrong_magic = bytes.clone();
    wrong_magic[0] = b'X';
    assert!(matches!(
        Model::parse(&wrong_magic),
        Err(LoadError::BadMagic { found }) if found == *b"XLWM"
    ));
    assert!(matches!(
        Model::parse(b"PK"),
        Err(LoadError::BadMagic { .. })
    ));

    // The version is the varint right after the magic (one byte below 128).
    for version in [0, FORMAT_VERSION + 1, 127] {
        let mut wrong_version = bytes.clone();
        wrong_version[4] = version as u8;
        assert_eq!(
            Model::parse(&wrong_version).err(),
            Some(LoadError::UnsupportedVersion {
                found: version,
                supported: FORMAT_VERSION
            })
        );
    }
    assert_eq!((OLDEST_FORMAT_VERSION, FORMAT_VERSION), (1, 4));
    // A validly written file of another version is refused the same way.
    let future = envelope_bytes(FORMAT_VERSION + 1, b"anything");
    assert!(matches!(
        Model::parse(&future),
        Err(LoadError::UnsupportedVersion { found, .. }) if found == FORMAT_VERSION + 1
    ));

    // Any flipped bit in the payload or in the stored checksum is a checksum error.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for _ in 0..200 {
        let mut corrupted = bytes.clone();
        let at = rng.random_range(8..bytes.len());
        corrupted[at] ^= 1 << rng.random_range(0..8);
        assert!(
            matches!(Model::parse(&corrupted), Err(LoadError::BadChecksum { .. })),
            "flip at {at}: {:?}",
            Model::parse(&corrupted).err()
        );
    }

    let mut longer = bytes.clone();
    longer.extend_from_slice(&[0, 0, 0]);
    assert_eq!(
        Model::parse(&longer).err(),
        Some(LoadError::TrailingBytes { count: 3 })
    );
}

#[test]
fn models_larger_than_the_buffers_are_refused_with_the_capacity() {
    let bytes = default_bytes();
    // Row buffer too short for the 516-wide dense input.
    assert_eq!(
        Policy::<4096, 300>::from_bytes(&bytes).err(),
        Some(LoadError::ExceedsCapacity {
            what: Capacity::RowElements,
            required: 516,
            capacity: 300
        })
    );
    assert_eq!(
        Policy::<4095, 1024>::from_bytes(&bytes).err(),
        Some(LoadError::ExceedsCapacity {
            what: Capacity::ActivationElements,
            required: 4096,
            capacity: 4095
        })
    );

    // A stride-1 first layer keeps 32 x 32 x 8 = 8192 activations: too large for the default.
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut arch = WeightsFile::shipped().architecture();
    arch.convs[0].out_channels = 8;
    arch.convs[0].stride = 1;
    arch.convs[1].in_channels = 8;
    let big = WeightsFile::synthetic(&mut rng, &arch).to_bytes();
    assert_eq!(
        DefaultPolicy::from_bytes(&big).err(),
        Some(LoadError::ExceedsCapacity {
            what: Capacity::ActivationElements,
            required: 8192,
            capacity: 4096
        })
    );
    assert!(Policy::<8192, 2052>::from_bytes(&big).is_ok());

    // More conv layers than the layer table holds.
    let mut deep = WeightsFile::shipped().architecture();
    deep.convs = (0..=MAX_CONV_LAYERS)
        .map(|_| ConvShape {
            in_channels: 1,
            out_channels: 1,
            kernel: 1,
            stride: 1,
            padding: 0,
        })
        .collect();
    let quantized = WeightsFile::synthetic(&mut rng, &deep);
    assert_eq!(
        Model::parse(&quantized.to_bytes()).err(),
        Some(LoadError::ExceedsCapacity {
            what: Capacity::ConvLayers,
            required: MAX_CONV_LAYERS + 1,
            capacity: MAX_CONV_LAYERS
        })
    );
}

#[test]
fn inconsistent_layers_are_shape_or_parameter_errors() {
    let good = WeightsFile::shipped();

    let mut short = good.clone();
    short.convs[1].layer.weights.pop();
    assert_eq!(
        Model::parse(&short.to_bytes()).err(),
        Some(LoadError::ShapeMismatch {
            layer: LayerRef::Conv(1),
            what: "weights bytes",
            expected: 32 * 9 * 16,
            found: 32 * 9 * 16 - 1
        })
    );

    let mut channels = good.clone();
    channels.convs[2].spec.in_channels = 16;
    assert!(matches!(
        Model::parse(&channels.to_bytes()),
        Err(LoadError::ShapeMismatch {
            layer: LayerRef::Conv(2),
            what: "input channels",
            ..
        })
    ));

    let mut head = good.clone();
    head.action_head.out_features = 14;
    head.action_head.layer.weights.truncate(14 * 128);
    head.action_head.layer.bias.pop();
    head.action_head.layer.multipliers.pop();
    head.action_head.layer.shifts.pop();
    assert_eq!(
        Model::parse(&head.to_bytes()).err(),
        Some(LoadError::ShapeMismatch {
            layer: LayerRef::ActionHead,
            what: "outputs",
            expected: 15,
            found: 14
        })
    );

    let mut dense_in = good.clone();
    dense_in.hidden[0].in_features = 512;
    assert!(matches!(
        Model::parse(&dense_in.to_bytes()),
        Err(LoadError::ShapeMismatch {
            layer: LayerRef::Dense(0),
            what: "input features",
            expected: 516,
            found: 512
        })
    ));

    let mut shift = good.clone();
    shift.hidden[0].layer.shifts[3] = 31;
    assert_eq!(
        Model::parse(&shift.to_bytes()).err(),
        Some(LoadError::InvalidParameter {
            layer: LayerRef::Dense(0),
            what: "shift"
        })
    );

    // Version 2 logits are symmetric int16 without ReLU; version 1 heads may have either.
    let mut logit_zero_point = good.clone();
    logit_zero_point.action_head.layer.output.zero_point = 3;
    assert_eq!(
        Model::parse(&logit_zero_point.to_bytes()).err(),
        Some(LoadError::InvalidParameter {
            layer: LayerRef::ActionHead,
            what: "logit zero point (must be 0)"
        })
    );
    let mut logit_relu = good.clone();
    logit_relu.action_head.layer.relu = true;
    assert_eq!(
        Model::parse(&logit_relu.to_bytes()).err(),
        Some(LoadError::InvalidParameter {
            layer: LayerRef::ActionHead,
            what: "ReLU on the logits"
        })
    );
    for mut old in [logit_zero_point, logit_relu] {
        old.version = 1;
        let bytes = old.to_bytes();
        let model = Model::parse(&bytes).unwrap();
        assert_eq!(model.version, 1);
        // Version 1: int8 state and logits; version 2: int16 both (what `inspect` prints).
        assert_eq!((model.state_bits(), model.logit_bits()), (8, 8));
    }
    let bytes = good.to_bytes();
    let current = Model::parse(&bytes).unwrap();
    assert_eq!((current.state_bits(), current.logit_bits()), (16, 16));

    let mut multiplier = good.clone();
    multiplier.action_head.layer.multipliers[0] = -1;
    assert_eq!(
        Model::parse(&multiplier.to_bytes()).err(),
        Some(LoadError::InvalidParameter {
            layer: LayerRef::ActionHead,
            what: "multiplier"
        })
    );

    let mut bias = good.clone();
    bias.convs[0].layer.bias[0] = i32::MAX;
    assert_eq!(
        Model::parse(&bias.to_bytes()).err(),
        Some(LoadError::InvalidParameter {
            layer: LayerRef::Conv(0),
            what: "bias magnitude"
        })
    );

    let mut stride = good.clone();
    stride.convs[0].spec.stride = 0;
    assert!(matches!(
        Model::parse(&stride.to_bytes()),
        Err(LoadError::InvalidParameter {
            layer: LayerRef::Conv(0),
            ..
        })
    ));

    // A payload with a valid envelope but garbage inside.
    assert!(matches!(
        Model::parse(&envelope_bytes(FORMAT_VERSION, &[0xff; 40])),
        Err(LoadError::Corrupt { .. })
    ));
}

/// Random mutations of whole files (caught by the checksum) and of payloads re-wrapped in a valid
/// envelope (which reach the record decoder and the validation): never a panic, and whatever
/// loads also runs.
#[test]
fn random_mutations_never_panic() {
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    let quantized = WeightsFile::shipped();
    let file = quantized.to_bytes();
    let payload = quantized.payload_bytes();
    // A small architecture too, so mutations hit the structure more often than the tensors.
    let small = WeightsFile::synthetic(
        &mut rng,
        &Architecture {
            height_rows: 6,
            height_cols: 5,
            state_len: 2,
            convs: vec![ConvShape {
                in_channels: 1,
                out_channels: 3,
                kernel: 3,
                stride: 2,
                padding: 1,
            }],
            hidden: vec![7],
            value_head: true,
        },
    );
    let small_payload = small.payload_bytes();
    let mut loaded = 0;
    for iteration in 0..10_000 {
        let (base, wrap) = match iteration % 3 {
            0 => (&file, false),
            1 => (&payload, true),
            _ => (&small_payload, true),
        };
        let mut bytes = base.clone();
        for _ in 0..rng.random_range(1..=4) {
            match rng.random_range(0..4) {
                0 if !bytes.is_empty() => {
                    let at = rng.random_range(0..bytes.len());
                    bytes[at] = rng.random();
                }
                1 if !bytes.is_empty() => {
                    let at = rng.random_range(0..bytes.len());
                    bytes.truncate(at);
                }
                2 => {
                    let at = rng.random_range(0..=bytes.len());
                    bytes.insert(at, rng.random());
                }
                _ if !bytes.is_empty() => {
                    let at = rng.random_range(0..bytes.len());
                    bytes.remove(at);
                }
                _ => {}
            }
        }
        let bytes = if wrap {
            envelope_bytes(FORMAT_VERSION, &bytes)
        } else {
            bytes
        };
        if let Ok(policy) = Policy::<65_536, 8_192>::from_bytes(&bytes) {
            loaded += 1;
            let model = policy.model();
            let cells = usize::from(model.input.rows) * usize::from(model.input.cols);
            let height = vec![150i16; cells];
            let state = vec![1000i32; model.state.len()];
            let outputs = policy.evaluate(&height, &state).unwrap();
            let _ = outputs.action();
        };
    }
    // Mutations of tensor bytes keep a file valid: some must load and run.
    assert!(loaded > 100, "only {loaded} mutated files loaded");
}

/// A change to a robot record.
type RecordEdit = fn(&mut wheelleg_runtime::model::format::RobotRecord<'_>);

/// A robot other than the shipped one: other lengths, wheels 2 cm outboard of their mounts,
/// nodes 21 to 36.
fn other_robot() -> TrainedRobot {
    let mut robot = Robot::WHEELLEG;
    robot.geometry.wheel_offset_m = 0.02;
    robot.geometry.thigh_m = 0.10;
    robot.geometry.shank_m = 0.20;
    robot.geometry.hip_x_m = 0.24;
    let ids: [NodeId; AXIS_COUNT] = core::array::from_fn(|i| NodeId::new(21 + i as u8).unwrap());
    robot.can = NodeMap::new(ids, robot.can.calibration).unwrap();
    TrainedRobot {
        name: "strider".into(),
        robot,
        bit_rate_bps: 500_000,
    }
}

#[test]
fn a_file_names_the_robot_it_was_trained_for() {
    // Before the robot record: the shipped robot.
    let shipped_bytes = default_bytes();
    let shipped = Model::parse(&shipped_bytes).unwrap();
    assert_eq!(shipped.trained_for, TrainedFor::SHIPPED);

    let mut file = WeightsFile::shipped();
    file.version = FORMAT_VERSION;
    file.robot = other_robot();
    let bytes = file.to_bytes();
    let model = Model::parse(&bytes).unwrap();
    assert_eq!(model.trained_for.name, "strider");
    assert_eq!(model.trained_for.robot, other_robot().robot);
    assert_eq!(model.trained_for.bit_rate_bps, 500_000);
    assert_eq!(WeightsFile::parse(&bytes), file);
    // Version 3 has no wheel offset: it reads as 0.
    file.version = 3;
    let version_3 = file.to_bytes();
    let model = Model::parse(&version_3).unwrap();
    assert_eq!(model.trained_for.robot.geometry.wheel_offset_m, 0.0);
    assert_eq!(model.trained_for.robot.geometry.thigh_m, 0.10);
    // The tensors are the same as version 2's: the same decisions.
    let a = DefaultPolicy::from_bytes(&shipped_bytes).unwrap();
    let b = DefaultPolicy::from_bytes(&bytes).unwrap();
    assert_eq!(a.model().tensor_bytes(), b.model().tensor_bytes());
}

#[test]
fn a_robot_the_runtime_cannot_drive_is_refused_by_what_is_wrong() {
    let mut cases: Vec<(TrainedRobot, &str)> = Vec::new();
    let mut bad = other_robot();
    bad.name = String::new();
    cases.push((bad, "name"));
    let mut bad = other_robot();
    bad.name = "a robot".into();
    cases.push((bad, "name"));
    let mut bad = other_robot();
    bad.name = "r".repeat(33);
    cases.push((bad, "name"));
    let mut bad = other_robot();
    bad.robot.geometry.shank_m = f32::NAN;
    cases.push((bad, "geometry: a length"));
    let mut bad = other_robot();
    bad.robot.geometry.knee_range_rad = [2.8, 0.0];
    cases.push((bad, "geometry: a range"));
    let mut bad = other_robot();
    bad.robot.geometry.wheel_offset_m = 0.05;
    cases.push((bad, "geometry: the wheel offset"));
    let mut bad = other_robot();
    bad.robot.geometry.default_clearance_m = 0.9;
    bad.robot.geometry.clearance_range_m = [0.04, 1.0];
    cases.push((bad, "geometry: the default pose"));
    let mut bad = other_robot();
    bad.robot.actions.yaw_step_deg = 0.0;
    cases.push((bad, "action lattice"));
    let mut bad = other_robot();
    bad.bit_rate_bps = 0;
    cases.push((bad, "bit rate"));
    for (robot, what) in cases {
        let mut file = WeightsFile::shipped();
        file.version = FORMAT_VERSION;
        file.robot = robot;
        assert_eq!(
            Model::parse(&file.to_bytes()).err(),
            Some(LoadError::InvalidRobot { what }),
        );
    }
    // The node map: a record with two axes on one node, one on node 0, a direction of 0.
    let mut file = WeightsFile::shipped();
    file.version = FORMAT_VERSION;
    let payload = file.payload_bytes();
    let record = RobotRecord::of("wheelleg", &Robot::WHEELLEG, 1_000_000);
    let mut encoded = Vec::new();
    push(&mut encoded, &record);
    let offset_len = core::mem::size_of::<f32>();
    let record_len = encoded.len() + offset_len;
    let head = &payload[..payload.len() - record_len];
    let edits: [(&str, RecordEdit); 3] = [
        ("node ids: two axes share one", |r| {
            r.node_ids[3] = r.node_ids[0]
        }),
        ("node ids: an axis on node 0", |r| r.node_ids[7] = 0),
        ("motor direction", |r| r.directions[12] = 0),
    ];
    for (what, edit) in edits {
        let mut record = record;
        edit(&mut record);
        let mut bytes = head.to_vec();
        push(&mut bytes, &record);
        push(&mut bytes, &0.0f32);
        assert_eq!(
            Model::parse(&envelope_bytes(FORMAT_VERSION, &bytes)).err(),
            Some(LoadError::InvalidRobot { what }),
        );
    }
}
