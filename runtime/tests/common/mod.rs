//! Shared by the runtime's tests: weights files as owned, editable values, read from and written
//! to bytes with the runtime's own format records (`model::format`), the shipped file, and
//! synthetic files of any architecture (valid random integer parameters, no float network).
#![allow(
    dead_code,
    clippy::unwrap_used,
    clippy::indexing_slicing,
    clippy::expect_used,
    clippy::std_instead_of_core
)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use wheelleg_runtime::model::crc32::crc32;
use wheelleg_runtime::model::format::{
    ActQuantRecord, ConvRecord, DenseRecord, Envelope, InputQuantRecord, InputRecord,
    FORMAT_VERSION, MAGIC,
};
use wheelleg_runtime::model::format::{RobotRecord, ROBOT_RECORD_VERSION, WHEEL_OFFSET_VERSION};
use wheelleg_runtime::model::load::{open_envelope, trained_for};
use wheelleg_runtime::robot::Robot;

mod inputs;
pub use inputs::raw_inputs_mm;

/// The shipped weights file (`weights/policy.wlw`, in the repository): the default architecture,
/// 3 convs 16-32-32 over the 32 x 32 map, 4 state features, one hidden layer of 128, the action
/// head and a value head, format version 2 (no robot record: trained for the shipped robot).
pub fn shipped_bytes() -> Vec<u8> {
    std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../weights/policy.wlw"
    ))
    .expect("weights/policy.wlw is committed with the repository")
}

/// Integer tensors and quantization of one conv or dense layer, as in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    /// int8 weights (conv: OHWI; dense: row-major `[out][in]`).
    pub weights: Vec<i8>,
    /// One per output.
    pub bias: Vec<i32>,
    /// One per output.
    pub multipliers: Vec<i32>,
    /// One per output.
    pub shifts: Vec<i8>,
    /// Output quantization.
    pub output: ActQuantRecord,
    /// Fused ReLU.
    pub relu: bool,
}

/// Shape of one conv layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConvShape {
    pub in_channels: usize,
    pub out_channels: usize,
    pub kernel: usize,
    pub stride: usize,
    pub padding: usize,
}

impl ConvShape {
    /// Output side for an input side (floor, as the runtime computes it).
    pub fn output_side(&self, side: usize) -> usize {
        (side + 2 * self.padding - self.kernel) / self.stride + 1
    }
}

/// One conv layer of a file.
#[derive(Clone, Debug, PartialEq)]
pub struct Conv {
    pub spec: ConvShape,
    pub layer: Layer,
}

/// One dense layer of a file.
#[derive(Clone, Debug, PartialEq)]
pub struct Dense {
    pub in_features: usize,
    pub out_features: usize,
    pub layer: Layer,
}

/// A whole weights file, owned and editable; [`WeightsFile::to_bytes`] writes it back.
#[derive(Clone, Debug, PartialEq)]
pub struct WeightsFile {
    pub version: u16,
    pub input: InputRecord,
    pub state: Vec<InputQuantRecord>,
    pub convs: Vec<Conv>,
    pub hidden: Vec<Dense>,
    pub action_head: Dense,
    pub value_head: Option<Dense>,
    /// The robot record (written from version 3 on): name, robot, bit rate.
    pub robot: TrainedRobot,
}

/// The robot a file was trained for, owned.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainedRobot {
    pub name: String,
    pub robot: Robot,
    pub bit_rate_bps: u32,
}

impl TrainedRobot {
    /// The shipped robot, what files before the robot record were trained for.
    pub fn shipped() -> TrainedRobot {
        TrainedRobot {
            name: "wheelleg".into(),
            robot: Robot::WHEELLEG,
            bit_rate_bps: 1_000_000,
        }
    }
}

/// An architecture for [`WeightsFile::synthetic`].
#[derive(Clone, Debug, PartialEq)]
pub struct Architecture {
    pub height_rows: usize,
    pub height_cols: usize,
    pub state_len: usize,
    pub convs: Vec<ConvShape>,
    pub hidden: Vec<usize>,
    pub value_head: bool,
}

/// Outputs of the action head (five 3-way heads).
pub const ACTION_OUTPUTS: usize = 15;

fn le_bytes(values: &[i32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn from_le(bytes: &[u8]) -> Vec<i32> {
    bytes
        .chunks_exact(4)
        .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn as_u8(values: &[i8]) -> Vec<u8> {
    values.iter().map(|&v| v as u8).collect()
}

fn as_i8(bytes: &[u8]) -> Vec<i8> {
    bytes.iter().map(|&b| b as i8).collect()
}

/// Byte tensors of a layer, as the records borrow them.
struct LayerBytes {
    weights: Vec<u8>,
    bias: Vec<u8>,
    multipliers: Vec<u8>,
    shifts: Vec<u8>,
}

impl Layer {
    fn bytes(&self) -> LayerBytes {
        LayerBytes {
            weights: as_u8(&self.weights),
            bias: le_bytes(&self.bias),
            multipliers: le_bytes(&self.multipliers),
            shifts: as_u8(&self.shifts),
        }
    }

    /// Random valid parameters: any int8 weight, small biases, multipliers in `[2^30, 2^31)`
    /// and shifts that keep the outputs spread over the int8 range.
    fn random(rng: &mut ChaCha8Rng, rows: usize, row_len: usize, relu: bool) -> Layer {
        let shift = -(((row_len as f64).sqrt() * 128.0).log2().round() as i8) + 2;
        Layer {
            weights: (0..rows * row_len).map(|_| rng.random()).collect(),
            bias: (0..rows).map(|_| rng.random_range(-5000..=5000)).collect(),
            multipliers: (0..rows)
                .map(|_| rng.random_range(1 << 30..i32::MAX))
                .collect(),
            shifts: vec![shift.clamp(-31, 30); rows],
            output: ActQuantRecord {
                scale: rng.random_range(0.01..0.1),
                zero_point: rng.random_range(-100..=20),
            },
            relu,
        }
    }
}

fn dense_record<'a>(dense: &Dense, bytes: &'a LayerBytes) -> DenseRecord<'a> {
    DenseRecord {
        in_features: dense.in_features as u16,
        out_features: dense.out_features as u16,
        relu: dense.layer.relu,
        output: dense.layer.output,
        weights: &bytes.weights,
        bias: &bytes.bias,
        multipliers: &bytes.multipliers,
        shifts: &bytes.shifts,
    }
}

fn dense_from(record: &DenseRecord<'_>) -> Dense {
    Dense {
        in_features: usize::from(record.in_features),
        out_features: usize::from(record.out_features),
        layer: Layer {
            weights: as_i8(record.weights),
            bias: from_le(record.bias),
            multipliers: from_le(record.multipliers),
            shifts: as_i8(record.shifts),
            output: record.output,
            relu: record.relu,
        },
    }
}

/// Appends the postcard encoding of `value`.
pub fn push<T: Serialize>(out: &mut Vec<u8>, value: &T) {
    let mut buffer = vec![0u8; 1 << 22];
    let used = postcard::to_slice(value, &mut buffer).unwrap().len();
    out.extend_from_slice(&buffer[..used]);
}

/// Decodes one postcard value from the front of `bytes`.
fn take<'a, T: serde::Deserialize<'a>>(bytes: &mut &'a [u8]) -> T {
    let (value, rest) = postcard::take_from_bytes::<T>(bytes).unwrap();
    *bytes = rest;
    value
}

/// A file of any version around any payload: magic, version, payload, CRC-32, as the format
/// describes it (whether or not this runtime reads that version).
pub fn envelope_bytes(version: u16, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    push(
        &mut out,
        &Envelope {
            magic: MAGIC,
            version,
            payload,
            crc32_le: [0; 4],
        },
    );
    out.truncate(out.len() - 4);
    let crc = crc32(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

impl WeightsFile {
    /// Reads a file this runtime accepts the envelope of (panics otherwise: test input).
    pub fn parse(bytes: &[u8]) -> WeightsFile {
        let (version, mut payload) = open_envelope(bytes).unwrap();
        let input: InputRecord = take(&mut payload);
        let count: u32 = take(&mut payload);
        let state = (0..count).map(|_| take(&mut payload)).collect();
        let count: u32 = take(&mut payload);
        let convs = (0..count)
            .map(|_| {
                let record: ConvRecord<'_> = take(&mut payload);
                Conv {
                    spec: ConvShape {
                        in_channels: usize::from(record.in_channels),
                        out_channels: usize::from(record.out_channels),
                        kernel: usize::from(record.kernel),
                        stride: usize::from(record.stride),
                        padding: usize::from(record.padding),
                    },
                    layer: Layer {
                        weights: as_i8(record.weights),
                        bias: from_le(record.bias),
                        multipliers: from_le(record.multipliers),
                        shifts: as_i8(record.shifts),
                        output: record.output,
                        relu: record.relu,
                    },
                }
            })
            .collect();
        let count: u32 = take(&mut payload);
        let hidden = (0..count)
            .map(|_| dense_from(&take::<DenseRecord<'_>>(&mut payload)))
            .collect();
        let action_head = dense_from(&take::<DenseRecord<'_>>(&mut payload));
        let value_head = take::<Option<DenseRecord<'_>>>(&mut payload).map(|r| dense_from(&r));
        let robot = if version >= ROBOT_RECORD_VERSION {
            let record: RobotRecord<'_> = take(&mut payload);
            let wheel_offset_m = if version >= WHEEL_OFFSET_VERSION {
                take::<f32>(&mut payload)
            } else {
                0.0
            };
            let found = trained_for(record, wheel_offset_m).unwrap();
            TrainedRobot {
                name: found.name.into(),
                robot: found.robot,
                bit_rate_bps: found.bit_rate_bps,
            }
        } else {
            TrainedRobot::shipped()
        };
        assert!(payload.is_empty(), "bytes after the last record");
        WeightsFile {
            version,
            input,
            state,
            convs,
            hidden,
            action_head,
            value_head,
            robot,
        }
    }

    /// The shipped file.
    pub fn shipped() -> WeightsFile {
        WeightsFile::parse(&shipped_bytes())
    }

    /// The payload: the parts of the format, one after another (the robot record from
    /// version 3 on).
    pub fn payload_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        push(&mut out, &self.input);
        push(&mut out, &(self.state.len() as u32));
        for quant in &self.state {
            push(&mut out, quant);
        }
        push(&mut out, &(self.convs.len() as u32));
        for conv in &self.convs {
            let bytes = conv.layer.bytes();
            push(
                &mut out,
                &ConvRecord {
                    in_channels: conv.spec.in_channels as u16,
                    out_channels: conv.spec.out_channels as u16,
                    kernel: conv.spec.kernel as u8,
                    stride: conv.spec.stride as u8,
                    padding: conv.spec.padding as u8,
                    relu: conv.layer.relu,
                    output: conv.layer.output,
                    weights: &bytes.weights,
                    bias: &bytes.bias,
                    multipliers: &bytes.multipliers,
                    shifts: &bytes.shifts,
                },
            );
        }
        push(&mut out, &(self.hidden.len() as u32));
        for dense in &self.hidden {
            let bytes = dense.layer.bytes();
            push(&mut out, &dense_record(dense, &bytes));
        }
        let bytes = self.action_head.layer.bytes();
        push(&mut out, &dense_record(&self.action_head, &bytes));
        let value = self
            .value_head
            .as_ref()
            .map(|head| (head, head.layer.bytes()));
        push(
            &mut out,
            &value
                .as_ref()
                .map(|(head, bytes)| dense_record(head, bytes)),
        );
        if self.version >= ROBOT_RECORD_VERSION {
            push(
                &mut out,
                &RobotRecord::of(&self.robot.name, &self.robot.robot, self.robot.bit_rate_bps),
            );
            if self.version >= WHEEL_OFFSET_VERSION {
                push(&mut out, &self.robot.robot.geometry.wheel_offset_m);
            }
        }
        out
    }

    /// The whole file.
    pub fn to_bytes(&self) -> Vec<u8> {
        envelope_bytes(self.version, &self.payload_bytes())
    }

    /// The file's architecture.
    pub fn architecture(&self) -> Architecture {
        Architecture {
            height_rows: usize::from(self.input.rows),
            height_cols: usize::from(self.input.cols),
            state_len: self.state.len(),
            convs: self.convs.iter().map(|conv| conv.spec).collect(),
            hidden: self.hidden.iter().map(|dense| dense.out_features).collect(),
            value_head: self.value_head.is_some(),
        }
    }

    /// A valid current-version file of `arch` with random integer parameters.
    pub fn synthetic(rng: &mut ChaCha8Rng, arch: &Architecture) -> WeightsFile {
        let quant = |rng: &mut ChaCha8Rng| InputQuantRecord {
            scale_m: 0.004,
            zero_point: rng.random_range(-128..=-100),
            multiplier: rng.random_range(1 << 30..i32::MAX),
            shift: -2,
        };
        let input = InputRecord {
            rows: arch.height_rows as u16,
            cols: arch.height_cols as u16,
            height: quant(rng),
        };
        let state = (0..arch.state_len).map(|_| quant(rng)).collect();
        let (mut h, mut w, mut c) = (arch.height_rows, arch.height_cols, 1);
        let convs = arch
            .convs
            .iter()
            .map(|&spec| {
                assert_eq!(spec.in_channels, c, "conv input channels");
                h = spec.output_side(h);
                w = spec.output_side(w);
                c = spec.out_channels;
                let row_len = spec.kernel * spec.kernel * spec.in_channels;
                Conv {
                    spec,
                    layer: Layer::random(rng, spec.out_channels, row_len, true),
                }
            })
            .collect();
        let mut width = h * w * c + arch.state_len;
        let hidden = arch
            .hidden
            .iter()
            .map(|&out| {
                let dense = Dense {
                    in_features: width,
                    out_features: out,
                    layer: Layer::random(rng, out, width, true),
                };
                width = out;
                dense
            })
            .collect();
        let mut head_layer = Layer::random(rng, ACTION_OUTPUTS, width, false);
        head_layer.output.zero_point = 0;
        let action_head = Dense {
            in_features: width,
            out_features: ACTION_OUTPUTS,
            layer: head_layer,
        };
        let value_head = arch.value_head.then(|| Dense {
            in_features: width,
            out_features: 1,
            layer: Layer::random(rng, 1, width, false),
        });
        WeightsFile {
            version: FORMAT_VERSION,
            input,
            state,
            convs,
            hidden,
            action_head,
            value_head,
            robot: TrainedRobot::shipped(),
        }
    }

    /// [`WeightsFile::synthetic`] from a seed.
    pub fn synthetic_seeded(seed: u64, arch: &Architecture) -> WeightsFile {
        WeightsFile::synthetic(&mut ChaCha8Rng::seed_from_u64(seed), arch)
    }
}

/// A random architecture of the family: 0-3 convs of random channels, kernel, stride and
/// padding on a random non-square map, 0-5 state features, 0-2 hidden layers, value head or not.
pub fn random_architecture(rng: &mut ChaCha8Rng) -> Architecture {
    let height_rows = rng.random_range(3..=20);
    let height_cols = rng.random_range(3..=20);
    let (mut h, mut w, mut c) = (height_rows, height_cols, 1);
    let mut convs = Vec::new();
    for _ in 0..rng.random_range(0..=3) {
        let mut kernel = rng.random_range(1..=4);
        let padding = rng.random_range(0..kernel.min(3));
        while h + 2 * padding < kernel || w + 2 * padding < kernel {
            kernel -= 1;
        }
        let spec = ConvShape {
            in_channels: c,
            out_channels: rng.random_range(1..=12),
            kernel,
            stride: rng.random_range(1..=3),
            padding: padding.min(kernel - 1),
        };
        h = spec.output_side(h);
        w = spec.output_side(w);
        c = spec.out_channels;
        convs.push(spec);
    }
    Architecture {
        height_rows,
        height_cols,
        state_len: rng.random_range(0..=5),
        convs,
        hidden: (0..rng.random_range(0..=2))
            .map(|_| rng.random_range(1..=40))
            .collect(),
        value_head: rng.random_bool(0.5),
    }
}

/// Raw integer inputs for `arch` ([`raw_inputs_mm`]).
pub fn random_inputs_mm(rng: &mut ChaCha8Rng, arch: &Architecture) -> (Vec<i16>, Vec<i32>) {
    raw_inputs_mm(rng, arch.height_rows * arch.height_cols, arch.state_len)
}
