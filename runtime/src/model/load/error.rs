//! What can be wrong with a weights file, named for the user.

use core::fmt;

use crate::model::format::{MAGIC, OLDEST_FORMAT_VERSION};

/// A layer, for error messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayerRef {
    /// The height-map / state input.
    Input,
    /// Conv layer number `n` (from 0).
    Conv(u8),
    /// Hidden dense layer number `n` (from 0).
    Dense(u8),
    /// The action head.
    ActionHead,
    /// The value head.
    ValueHead,
}

/// A compile-time capacity that a model can exceed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Capacity {
    /// [`super::MAX_CONV_LAYERS`].
    ConvLayers,
    /// [`super::MAX_DENSE_LAYERS`].
    DenseLayers,
    /// [`super::MAX_STATE_FEATURES`].
    StateFeatures,
    /// [`super::MAX_DOT_LEN`], the format's own bound on inputs per output.
    DotLengthLimit,
    /// Elements of one activation buffer (the policy's `ACT` parameter).
    ActivationElements,
    /// Length of the widened input row (the policy's `ROW` parameter).
    RowElements,
}

/// Why a weights file was refused. Every check happens at load time; none of these can come out
/// of inference.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoadError {
    /// The bytes end before the file does.
    Truncated,
    /// The first four bytes are not [`MAGIC`].
    BadMagic {
        /// What the file starts with (zero-padded if shorter).
        found: [u8; 4],
    },
    /// A format version this runtime does not read (it reads [`OLDEST_FORMAT_VERSION`] to
    /// [`crate::model::format::FORMAT_VERSION`]).
    UnsupportedVersion {
        /// Version in the file.
        found: u16,
        /// Newest version this runtime reads.
        supported: u16,
    },
    /// The stored CRC-32 does not match the bytes.
    BadChecksum {
        /// CRC in the file.
        stored: u32,
        /// CRC of the bytes.
        computed: u32,
    },
    /// Bytes follow the checksum.
    TrailingBytes {
        /// How many.
        count: usize,
    },
    /// A part could not be decoded although the checksum matched (a writer bug).
    Corrupt {
        /// Which part.
        part: &'static str,
    },
    /// A tensor length or a layer size disagrees with the architecture.
    ShapeMismatch {
        /// The layer.
        layer: LayerRef,
        /// Which quantity.
        what: &'static str,
        /// The size the architecture implies.
        expected: usize,
        /// The size in the file.
        found: usize,
    },
    /// A parameter outside the range the arithmetic is defined for (zero stride, shift out of
    /// range, negative multiplier, bias too large, ...).
    InvalidParameter {
        /// The layer.
        layer: LayerRef,
        /// Which parameter.
        what: &'static str,
    },
    /// The robot record (version 3 on) describes a robot the runtime cannot drive.
    InvalidRobot {
        /// What is wrong with it.
        what: &'static str,
    },
    /// The model needs more than a compile-time capacity.
    ExceedsCapacity {
        /// Which capacity.
        what: Capacity,
        /// What the model needs.
        required: usize,
        /// What was compiled in.
        capacity: usize,
    },
}

impl fmt::Display for LoadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LoadError::Truncated => write!(f, "weights file is truncated"),
            LoadError::BadMagic { found } => {
                write!(
                    f,
                    "not a weights file (magic {found:?}, expected {MAGIC:?})"
                )
            }
            LoadError::UnsupportedVersion { found, supported } => write!(
                f,
                "weights format version {found} is not supported (this runtime reads \
                 {OLDEST_FORMAT_VERSION} to {supported})"
            ),
            LoadError::BadChecksum { stored, computed } => write!(
                f,
                "checksum mismatch: stored {stored:#010x}, computed {computed:#010x}"
            ),
            LoadError::TrailingBytes { count } => {
                write!(f, "{count} unexpected bytes after the checksum")
            }
            LoadError::Corrupt { part } => write!(f, "cannot decode {part}"),
            LoadError::ShapeMismatch {
                layer,
                what,
                expected,
                found,
            } => write!(
                f,
                "{layer:?}: {what} is {found}, the architecture implies {expected}"
            ),
            LoadError::InvalidParameter { layer, what } => {
                write!(f, "{layer:?}: invalid {what}")
            }
            LoadError::InvalidRobot { what } => {
                write!(f, "the robot the policy was trained for: invalid {what}")
            }
            LoadError::ExceedsCapacity {
                what,
                required,
                capacity,
            } => write!(
                f,
                "model needs {required} {what:?} but the runtime was built for {capacity}"
            ),
        }
    }
}
