//! The `.wlw` weights file: records as they are stored, and the envelope around them.
//!
//! A file is the postcard encoding of [`Envelope`]: the magic bytes, the format version, the
//! payload (a length-prefixed byte string) and a CRC-32 of everything before it. The payload is
//! the postcard encoding, field after field, of:
//!
//! 1. [`InputRecord`]: the height-map shape and its quantization;
//! 2. a sequence of [`InputQuantRecord`] (one per state feature);
//! 3. a sequence of [`ConvRecord`] (the conv stack, first layer first);
//! 4. a sequence of [`DenseRecord`] (the hidden dense stack);
//! 5. one [`DenseRecord`] (the action head);
//! 6. an `Option<DenseRecord>` (the value head);
//! 7. from version 3 on, a [`RobotRecord`]: the robot the policy was trained for;
//! 8. from version 4 on, the robot's wheel offset along its axle (`f32`, metres), which the
//!    version 3 record lacks (version 3 files are read with an offset of 0).
//!
//! A writer with an allocator serializes a struct with these six fields (sequences as `Vec`s,
//! as the trainer does), which gives exactly those bytes; the runtime reads the six parts one after another
//! so that it can check every sequence length against its capacity before storing anything.
//! Tensors are byte strings borrowed from the file, never copied. The byte-level description for
//! other readers is docs/weights-format.md.
//!
//! Versions. Version 2 (written since the int16 action head) has the same bytes as version 1;
//! two things mean something else. (1) The action head's output: in version 1 an int8 tensor
//! with the `output` record's scale and zero point, like every other layer; in version 2 int16
//! logits, symmetric: `output.scale` is real units per int16 step, `output.zero_point` must be 0
//! and `relu` false. Why: the robot acts on the argmax of each 3-way head, and the trained
//! policy has many near ties (1% of head decisions have a float margin under 0.034 at a logit
//! range of 40); rounding the logits to 255 int8 steps alone flipped 1.1% of head decisions.
//! At 16 bits the argmax is decided by the int32 accumulator, not by output rounding. (2) The
//! state features: in version 1 each is an int8 slot of the flattened vector; in version 2 each
//! is an int16, the int8 grid refined [`STATE_FRACTION_BITS`] bits (`scale_m` is metres per
//! int16 step, the int16 zero point is `256 * zero_point`), and the layer that reads them adds
//! their products with its (unchanged, folded) int8 weight columns as a separate sum divided by
//! 256, rounded. Why: the target position on a 7.8 mm int8 grid alone flipped 0.58% of the
//! trained policy's move-y decisions. Version 2 was amended with (2) before any release outside
//! the repository. The runtime reads both versions (a version 1 head becomes int16 logits with
//! the int8 clamp, see `load`), so old files keep working.

use serde::{Deserialize, Serialize};

/// First four bytes of every weights file.
pub const MAGIC: [u8; 4] = *b"WLWM";
/// The format version the trainer writes and the newest this runtime reads (int16 action
/// logits, the robot record with the wheel offset; see the module docs).
pub const FORMAT_VERSION: u16 = 4;
/// The first version whose payload ends with a [`RobotRecord`]. Files of earlier versions were
/// all trained for the shipped robot ([`crate::robot::Robot::WHEELLEG`]), which the loader
/// takes for them.
pub const ROBOT_RECORD_VERSION: u16 = 3;
/// The first version whose payload ends with the wheel offset after the [`RobotRecord`].
pub const WHEEL_OFFSET_VERSION: u16 = 4;
/// Longest robot name a file may carry, in bytes.
pub const MAX_ROBOT_NAME_BYTES: usize = 32;
/// The oldest format version this runtime reads (int8 action logits and state).
pub const OLDEST_FORMAT_VERSION: u16 = 1;
/// Bits by which a version 2 state feature refines its int8 grid: the feature is an int16
/// `u = clamp(256 * zero_point + rescale(mm), -32768, 32767)` (`u / 256` is the value in steps
/// of the version 1 int8 grid, before that grid's rounding), and the first layer's partial sum over the state columns is divided by
/// `2^STATE_FRACTION_BITS` (rounded) before it joins the int8-domain accumulator. Fixed, so
/// that the int8 weight folding of version 1 stays exactly as it is (see docs/weights-format.md,
/// "Flatten and state").
pub const STATE_FRACTION_BITS: u32 = 8;

/// The outer layer of the file. Serialized with postcard: 4 raw magic bytes, the version as a
/// varint, the payload as varint length + bytes, then the 4 CRC bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Envelope<'a> {
    /// [`MAGIC`].
    pub magic: [u8; 4],
    /// [`OLDEST_FORMAT_VERSION`] to [`FORMAT_VERSION`] for files this runtime reads.
    pub version: u16,
    /// The postcard-encoded model (see the module docs).
    #[serde(borrow)]
    pub payload: &'a [u8],
    /// CRC-32 (see [`super::crc32`]) of every file byte before these four, little-endian.
    pub crc32_le: [u8; 4],
}

/// Quantization of one activation tensor: real value = `scale * (q - zero_point)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ActQuantRecord {
    /// Real units per integer step (metres for inputs; the network's own units inside).
    pub scale: f32,
    /// The integer that stands for real 0.
    pub zero_point: i8,
}

/// How one raw input in millimetres becomes an integer, in integers only:
/// `q = clamp(zero_point + requantize(value_mm, multiplier, shift), -128, 127)` where
/// `requantize` is [`super::quant::requantize`] (multiply by `multiplier * 2^(shift - 31)`,
/// rounded). The height map always, and the state features of a version 1 file. A version 2
/// state feature is int16: `u = clamp(256 * zero_point + requantize(..), -32768, 32767)` (see
/// [`STATE_FRACTION_BITS`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct InputQuantRecord {
    /// Real metres per integer step (informational: lets readers dequantize); for a version 2
    /// state feature, per int16 step.
    pub scale_m: f32,
    /// The integer that stands for 0 m (a version 2 state feature: its int8-grid value, the
    /// int16 zero point is 256 times it).
    pub zero_point: i8,
    /// Fixed-point multiplier, in `[0, 2^31)` (`1 mm / scale_m` = `multiplier * 2^(shift-31)`).
    pub multiplier: i32,
    /// Power-of-two exponent of the multiplier, in `[-31, 30]`.
    pub shift: i8,
}

/// The height-map input: shape and quantization.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct InputRecord {
    /// Rows of the height map (robot x, forward).
    pub rows: u16,
    /// Columns of the height map (robot y, left).
    pub cols: u16,
    /// Millimetres to int8.
    pub height: InputQuantRecord,
}

/// One 2-D convolution with a square kernel, optional ReLU, int8 in and out.
///
/// Weights are int8 in `[out][ky][kx][in]` order (OHWI, channels innermost, matching the
/// runtime's HWC activations). `bias`, `multipliers` are little-endian i32 per output channel;
/// `shifts` one i8 per output channel. Padding cells hold the input zero point (real 0).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConvRecord<'a> {
    /// Input channels.
    pub in_channels: u16,
    /// Output channels.
    pub out_channels: u16,
    /// Kernel side (square kernel).
    pub kernel: u8,
    /// Stride, both axes.
    pub stride: u8,
    /// Zero padding on every side.
    pub padding: u8,
    /// Whether ReLU is fused (the output is clamped below at the zero point).
    pub relu: bool,
    /// Output activation quantization.
    pub output: ActQuantRecord,
    /// `out * kernel * kernel * in` int8 weights, OHWI.
    #[serde(borrow)]
    pub weights: &'a [u8],
    /// `out` little-endian i32 biases, in units of input scale * weight scale.
    #[serde(borrow)]
    pub bias: &'a [u8],
    /// `out` little-endian i32 requantization multipliers.
    #[serde(borrow)]
    pub multipliers: &'a [u8],
    /// `out` i8 requantization shifts.
    #[serde(borrow)]
    pub shifts: &'a [u8],
}

/// One fully connected layer, optional ReLU, int8 in and int8 out (the action head of a version
/// 2 file: int16 out, zero point 0, no ReLU). Weights are int8 `[out][in]`, row-major; bias,
/// multipliers and shifts as in [`ConvRecord`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DenseRecord<'a> {
    /// Input features.
    pub in_features: u16,
    /// Output features.
    pub out_features: u16,
    /// Whether ReLU is fused (never for a version 2 action head).
    pub relu: bool,
    /// Output quantization (version 2 action head: the int16 logits' scale, zero point 0).
    pub output: ActQuantRecord,
    /// `out * in` int8 weights, row-major.
    #[serde(borrow)]
    pub weights: &'a [u8],
    /// `out` little-endian i32 biases.
    #[serde(borrow)]
    pub bias: &'a [u8],
    /// `out` little-endian i32 requantization multipliers.
    #[serde(borrow)]
    pub multipliers: &'a [u8],
    /// `out` i8 requantization shifts.
    #[serde(borrow)]
    pub shifts: &'a [u8],
}

/// The robot a policy was trained for (version 3 on): its name, geometry, action lattice and
/// CAN wiring, everything the runtime needs to drive it. The loader checks it as a robot
/// description is checked (lengths, ranges, a default pose with a leg solution, the node map)
/// and refuses a file whose robot cannot be driven.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RobotRecord<'a> {
    /// The robot's name (letters, digits, `-`, `_`; at most [`MAX_ROBOT_NAME_BYTES`]).
    #[serde(borrow)]
    pub name: &'a str,
    /// [`crate::robot::RobotGeometry`]'s fields in declaration order
    /// ([`crate::robot::RobotGeometry::to_array`]).
    pub geometry: [f32; crate::robot::GEOMETRY_FIELDS],
    /// [`crate::action::ActionLattice`]: move step (m), yaw step (degrees), clearance step (m),
    /// track step (m).
    pub actions: [f32; 4],
    /// Each axis's CAN node id, in [`crate::can::Axis::ALL`] order.
    pub node_ids: [u8; crate::can::node_map::AXIS_COUNT],
    /// Each axis's motor direction, +1 or -1.
    pub directions: [i8; crate::can::node_map::AXIS_COUNT],
    /// Each axis's gear ratio (motor turns per output turn).
    pub gear_ratios: [f32; crate::can::node_map::AXIS_COUNT],
    /// The bus's bit rate.
    pub bit_rate_bps: u32,
}

impl<'a> RobotRecord<'a> {
    /// The record that stores `robot` under `name` (for writers).
    pub fn of(name: &'a str, robot: &crate::robot::Robot, bit_rate_bps: u32) -> RobotRecord<'a> {
        let map = &robot.can;
        let a = &robot.actions;
        RobotRecord {
            name,
            geometry: robot.geometry.to_array(),
            actions: [
                a.move_step_m,
                a.yaw_step_deg,
                a.clearance_step_m,
                a.track_step_m,
            ],
            node_ids: crate::can::Axis::ALL.map(|axis| map.node_id(axis).get()),
            directions: crate::can::Axis::ALL.map(|axis| {
                if map.get(axis).direction < 0.0 {
                    -1
                } else {
                    1
                }
            }),
            gear_ratios: crate::can::Axis::ALL.map(|axis| map.get(axis).gear_ratio),
            bit_rate_bps,
        }
    }
}
