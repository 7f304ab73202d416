//! A quantized network as the bytes of a weights file: the payload in the runtime's record
//! order (postcard), wrapped in the envelope with its magic, version and CRC.

use serde::Serialize;
use wheelleg_runtime::model::crc32::crc32;
use wheelleg_runtime::model::format::{
    ActQuantRecord, ConvRecord, DenseRecord, Envelope, InputQuantRecord, InputRecord, RobotRecord,
    FORMAT_VERSION, MAGIC, OLDEST_FORMAT_VERSION, ROBOT_RECORD_VERSION, WHEEL_OFFSET_VERSION,
};

use super::params::ActQuant;

use super::build::{InputQuant, QuantizeError, QuantizedDense, QuantizedLayer, QuantizedNetwork};

/// The file's payload in the order of `wheelleg_runtime::model::format` (sequences as `Vec`s).
#[derive(Serialize)]
struct Payload<'a> {
    input: InputRecord,
    state: Vec<InputQuantRecord>,
    convs: Vec<ConvRecord<'a>>,
    hidden: Vec<DenseRecord<'a>>,
    action_head: DenseRecord<'a>,
    value_head: Option<DenseRecord<'a>>,
}

/// A layer's tensors as the little-endian bytes the file stores.
struct LayerBytes {
    weights: Vec<u8>,
    bias: Vec<u8>,
    multipliers: Vec<u8>,
    shifts: Vec<u8>,
}

impl LayerBytes {
    fn new(layer: &QuantizedLayer) -> LayerBytes {
        let le = |values: &[i32]| values.iter().flat_map(|v| v.to_le_bytes()).collect();
        LayerBytes {
            weights: layer.weights.iter().map(|&w| w as u8).collect(),
            bias: le(&layer.bias),
            multipliers: le(&layer.multipliers),
            shifts: layer.shifts.iter().map(|&s| s as u8).collect(),
        }
    }
}

fn u16_of(value: usize, what: &str) -> Result<u16, QuantizeError> {
    u16::try_from(value).map_err(|_| QuantizeError::TooLarge {
        what: format!("{what} ({value})"),
    })
}

fn u8_of(value: usize, what: &str) -> Result<u8, QuantizeError> {
    u8::try_from(value).map_err(|_| QuantizeError::TooLarge {
        what: format!("{what} ({value})"),
    })
}

fn input_record(quant: &InputQuant) -> InputQuantRecord {
    InputQuantRecord {
        // Metres per stored integer step (int16 steps for a version 2 state feature).
        scale_m: quant.act.scale / (1u32 << quant.fraction_bits) as f32,
        zero_point: quant.act.zero_point,
        multiplier: quant.multiplier,
        shift: quant.shift,
    }
}

fn act_record(quant: ActQuant) -> ActQuantRecord {
    ActQuantRecord {
        scale: quant.scale,
        zero_point: quant.zero_point,
    }
}

fn dense_record<'a>(
    dense: &QuantizedDense,
    bytes: &'a LayerBytes,
) -> Result<DenseRecord<'a>, QuantizeError> {
    Ok(DenseRecord {
        in_features: u16_of(dense.in_features, "dense inputs")?,
        out_features: u16_of(dense.out_features, "dense outputs")?,
        relu: dense.layer.relu,
        output: act_record(dense.layer.output),
        weights: &bytes.weights,
        bias: &bytes.bias,
        multipliers: &bytes.multipliers,
        shifts: &bytes.shifts,
    })
}

/// The end of a version 3 or later payload: the robot record of `robot` under `name`, and from
/// version 4 on its wheel offset.
pub fn robot_bytes(
    version: u16,
    name: &str,
    robot: &wheelleg_runtime::robot::Robot,
    bit_rate_bps: u32,
) -> Result<Vec<u8>, QuantizeError> {
    let encode = |e: postcard::Error| QuantizeError::Encode(e.to_string());
    let record = RobotRecord::of(name, robot, bit_rate_bps);
    let mut bytes = postcard::to_allocvec(&record).map_err(encode)?;
    if version >= WHEEL_OFFSET_VERSION {
        bytes.extend(postcard::to_allocvec(&robot.geometry.wheel_offset_m).map_err(encode)?);
    }
    Ok(bytes)
}

/// Wraps a payload in the envelope: magic, version, payload, CRC-32 of all that.
pub fn envelope_bytes(version: u16, payload: &[u8]) -> Result<Vec<u8>, QuantizeError> {
    let envelope = Envelope {
        magic: MAGIC,
        version,
        payload,
        crc32_le: [0; 4],
    };
    let mut bytes =
        postcard::to_allocvec(&envelope).map_err(|e| QuantizeError::Encode(e.to_string()))?;
    let covered = bytes.len() - 4;
    let crc = crc32(&bytes[..covered]);
    bytes[covered..].copy_from_slice(&crc.to_le_bytes());
    Ok(bytes)
}

impl QuantizedNetwork {
    /// The postcard-encoded payload (everything inside the envelope).
    pub fn payload_bytes(&self) -> Result<Vec<u8>, QuantizeError> {
        let conv_bytes: Vec<LayerBytes> = self
            .convs
            .iter()
            .map(|c| LayerBytes::new(&c.layer))
            .collect();
        let hidden_bytes: Vec<LayerBytes> = self
            .hidden
            .iter()
            .map(|d| LayerBytes::new(&d.layer))
            .collect();
        let action_bytes = LayerBytes::new(&self.action_head.layer);
        let value_bytes = self.value_head.as_ref().map(|d| LayerBytes::new(&d.layer));

        let convs = self
            .convs
            .iter()
            .zip(&conv_bytes)
            .map(|(conv, bytes)| {
                Ok(ConvRecord {
                    in_channels: u16_of(conv.spec.in_channels, "conv input channels")?,
                    out_channels: u16_of(conv.spec.out_channels, "conv output channels")?,
                    kernel: u8_of(conv.spec.kernel, "conv kernel")?,
                    stride: u8_of(conv.spec.stride, "conv stride")?,
                    padding: u8_of(conv.spec.padding, "conv padding")?,
                    relu: conv.layer.relu,
                    output: act_record(conv.layer.output),
                    weights: &bytes.weights,
                    bias: &bytes.bias,
                    multipliers: &bytes.multipliers,
                    shifts: &bytes.shifts,
                })
            })
            .collect::<Result<Vec<_>, QuantizeError>>()?;
        let hidden = self
            .hidden
            .iter()
            .zip(&hidden_bytes)
            .map(|(dense, bytes)| dense_record(dense, bytes))
            .collect::<Result<Vec<_>, _>>()?;
        let payload = Payload {
            input: InputRecord {
                rows: u16_of(self.arch.height_rows, "height map rows")?,
                cols: u16_of(self.arch.height_cols, "height map columns")?,
                height: input_record(&self.height),
            },
            state: self.state.iter().map(input_record).collect(),
            convs,
            hidden,
            action_head: dense_record(&self.action_head, &action_bytes)?,
            value_head: match (&self.value_head, &value_bytes) {
                (Some(head), Some(bytes)) => Some(dense_record(head, bytes)?),
                _ => None,
            },
        };
        let mut bytes =
            postcard::to_allocvec(&payload).map_err(|e| QuantizeError::Encode(e.to_string()))?;
        if self.version >= ROBOT_RECORD_VERSION {
            // The seventh part: postcard lays out a struct as its fields one after another, so
            // appending the record is the payload with the record as a last field.
            let robot = &self.robot;
            bytes.extend(robot_bytes(
                self.version,
                &robot.name,
                &robot.robot,
                robot.bit_rate_bps,
            )?);
        }
        Ok(bytes)
    }

    /// The complete `.wlw` file, of format version [`QuantizedNetwork::version`] (the payload
    /// bytes are laid out the same in versions 1 and 2, only the head's meaning differs;
    /// version 3 adds the robot record, version 4 the wheel offset after it).
    pub fn to_bytes(&self) -> Result<Vec<u8>, QuantizeError> {
        if !(OLDEST_FORMAT_VERSION..=FORMAT_VERSION).contains(&self.version) {
            return Err(QuantizeError::Version(self.version));
        }
        envelope_bytes(self.version, &self.payload_bytes()?)
    }
}
