//! Decoding the records of a weights file and checking every length and range inference
//! relies on.

use serde::Deserialize;

use super::{Capacity, DenseLayer, LayerRef, Linear, LoadError, MAX_BIAS_ABS, MAX_DOT_LEN};
use crate::model::crc32::crc32;
use crate::model::format::{
    ActQuantRecord, DenseRecord, InputQuantRecord, FORMAT_VERSION, MAGIC, OLDEST_FORMAT_VERSION,
};
use crate::model::quant::{MAX_SHIFT, MIN_SHIFT};

/// Decodes one postcard value from the front of `bytes`.
pub(super) fn take<'a, T: Deserialize<'a>>(
    bytes: &'a [u8],
    truncated: LoadError,
    part: &'static str,
) -> Result<(T, &'a [u8]), LoadError> {
    postcard::take_from_bytes::<T>(bytes).map_err(|error| match error {
        postcard::Error::DeserializeUnexpectedEnd => truncated,
        _ => LoadError::Corrupt { part },
    })
}

/// Decodes a sequence length and checks it against a capacity before anything is stored.
pub(super) fn take_len<'a>(
    bytes: &'a [u8],
    part: &'static str,
    what: Capacity,
    capacity: usize,
) -> Result<(usize, &'a [u8]), LoadError> {
    let (len, rest) = take::<u32>(bytes, LoadError::Corrupt { part }, part)?;
    let len = usize::try_from(len).map_err(|_| LoadError::Corrupt { part })?;
    if len > capacity {
        return Err(LoadError::ExceedsCapacity {
            what,
            required: len,
            capacity,
        });
    }
    Ok((len, rest))
}

/// Splits a file into its version and checked payload: magic, then version, then structure,
/// then checksum, so that each failure gets the most specific error.
pub fn open_envelope(bytes: &[u8]) -> Result<(u16, &[u8]), LoadError> {
    let mut found = [0u8; 4];
    for (slot, byte) in found.iter_mut().zip(bytes) {
        *slot = *byte;
    }
    if bytes.len() < MAGIC.len() {
        return if bytes == MAGIC.get(..bytes.len()).unwrap_or(&[]) {
            Err(LoadError::Truncated)
        } else {
            Err(LoadError::BadMagic { found })
        };
    }
    if found != MAGIC {
        return Err(LoadError::BadMagic { found });
    }
    let after_magic = bytes.get(MAGIC.len()..).ok_or(LoadError::Truncated)?;
    let (version, rest) = take::<u16>(after_magic, LoadError::Truncated, "version")?;
    if !(OLDEST_FORMAT_VERSION..=FORMAT_VERSION).contains(&version) {
        return Err(LoadError::UnsupportedVersion {
            found: version,
            supported: FORMAT_VERSION,
        });
    }
    let (payload, rest) = take::<&[u8]>(rest, LoadError::Truncated, "payload")?;
    let (stored, rest) = take::<[u8; 4]>(rest, LoadError::Truncated, "checksum")?;
    if !rest.is_empty() {
        return Err(LoadError::TrailingBytes { count: rest.len() });
    }
    // Everything but the last four bytes is covered by the checksum.
    let covered = bytes
        .get(..bytes.len().saturating_sub(4))
        .ok_or(LoadError::Truncated)?;
    let stored = u32::from_le_bytes(stored);
    let computed = crc32(covered);
    if stored != computed {
        return Err(LoadError::BadChecksum { stored, computed });
    }
    Ok((version, payload))
}

/// Little-endian i32 number `index` of a byte tensor (0 past the end: lengths were checked).
#[inline(always)]
pub fn i32_at(bytes: &[u8], index: usize) -> i32 {
    let start = index.saturating_mul(4);
    match bytes.get(start..start.saturating_add(4)) {
        Some(&[a, b, c, d]) => i32::from_le_bytes([a, b, c, d]),
        _ => 0,
    }
}

pub(super) fn expect_len(
    layer: LayerRef,
    what: &'static str,
    expected: usize,
    found: usize,
) -> Result<(), LoadError> {
    if expected == found {
        Ok(())
    } else {
        Err(LoadError::ShapeMismatch {
            layer,
            what,
            expected,
            found,
        })
    }
}

pub(super) fn check_input_quant(
    layer: LayerRef,
    quant: &InputQuantRecord,
) -> Result<(), LoadError> {
    if quant.multiplier < 0 {
        return Err(LoadError::InvalidParameter {
            layer,
            what: "input multiplier",
        });
    }
    if !(MIN_SHIFT..=MAX_SHIFT).contains(&quant.shift) {
        return Err(LoadError::InvalidParameter {
            layer,
            what: "input shift",
        });
    }
    Ok(())
}

/// Checks the tensors and requantization parameters shared by conv and dense layers.
#[allow(clippy::too_many_arguments)]
pub(super) fn check_linear<'a>(
    layer: LayerRef,
    weights: &'a [u8],
    bias: &'a [u8],
    multipliers: &'a [u8],
    shifts: &'a [u8],
    rows: usize,
    row_len: usize,
    input_zero_point: i8,
    output: ActQuantRecord,
    relu: bool,
) -> Result<Linear<'a>, LoadError> {
    if rows == 0 || row_len == 0 {
        return Err(LoadError::InvalidParameter {
            layer,
            what: "empty layer",
        });
    }
    if row_len > MAX_DOT_LEN {
        return Err(LoadError::ExceedsCapacity {
            what: Capacity::DotLengthLimit,
            required: row_len,
            capacity: MAX_DOT_LEN,
        });
    }
    expect_len(
        layer,
        "weights bytes",
        rows.saturating_mul(row_len),
        weights.len(),
    )?;
    expect_len(layer, "bias bytes", rows.saturating_mul(4), bias.len())?;
    expect_len(
        layer,
        "multiplier bytes",
        rows.saturating_mul(4),
        multipliers.len(),
    )?;
    expect_len(layer, "shift bytes", rows, shifts.len())?;
    let (output_low, output_high) = Linear::int8_bounds(output.zero_point, relu);
    for row in 0..rows {
        let b = i32_at(bias, row);
        if b.unsigned_abs() > MAX_BIAS_ABS.unsigned_abs() {
            return Err(LoadError::InvalidParameter {
                layer,
                what: "bias magnitude",
            });
        }
        if i32_at(multipliers, row) < 0 {
            return Err(LoadError::InvalidParameter {
                layer,
                what: "multiplier",
            });
        }
    }
    if shifts
        .iter()
        .any(|&s| !(MIN_SHIFT..=MAX_SHIFT).contains(&(s as i8)))
    {
        return Err(LoadError::InvalidParameter {
            layer,
            what: "shift",
        });
    }
    Ok(Linear {
        weights,
        bias,
        multipliers,
        shifts,
        rows,
        row_len,
        input_zero_point,
        output_zero_point: output.zero_point,
        relu,
        output_low,
        output_high,
    })
}

pub(super) fn dense_layer<'a>(
    layer: LayerRef,
    record: DenseRecord<'a>,
    in_features: usize,
    input_zero_point: i8,
) -> Result<DenseLayer<'a>, LoadError> {
    expect_len(
        layer,
        "input features",
        in_features,
        usize::from(record.in_features),
    )?;
    let linear = check_linear(
        layer,
        record.weights,
        record.bias,
        record.multipliers,
        record.shifts,
        usize::from(record.out_features),
        in_features,
        input_zero_point,
        record.output,
        record.relu,
    )?;
    Ok(DenseLayer { record, linear })
}

/// The action head's arithmetic as int16 logits with zero point 0, for either version.
///
/// Version 2 stores them so: the record's zero point must be 0 and ReLU off (a logit head has
/// no use for either, and refusing them keeps one meaning per file). A version 1 head is int8
/// `q = clamp(zp + r, low, 127)` read as real `scale * (q - zp)`; as the logit `q - zp` that is
/// `clamp(r, low - zp, 127 - zp)`, the same values and argmax, so version 1 files run through
/// the same int16 path with narrower bounds instead of a second code path.
pub(super) fn logit_head<'a>(
    version: u16,
    linear: Linear<'a>,
    record: DenseRecord<'a>,
) -> Result<Linear<'a>, LoadError> {
    let zero_point = record.output.zero_point;
    if version >= 2 {
        if zero_point != 0 {
            return Err(LoadError::InvalidParameter {
                layer: LayerRef::ActionHead,
                what: "logit zero point (must be 0)",
            });
        }
        if record.relu {
            return Err(LoadError::InvalidParameter {
                layer: LayerRef::ActionHead,
                what: "ReLU on the logits",
            });
        }
        return Ok(Linear {
            output_low: i16::MIN,
            output_high: i16::MAX,
            ..linear
        });
    }
    let (low, high) = Linear::int8_bounds(zero_point, record.relu);
    Ok(Linear {
        output_zero_point: 0,
        output_low: low - i16::from(zero_point),
        output_high: high - i16::from(zero_point),
        ..linear
    })
}

pub(super) fn layer_index(index: usize) -> u8 {
    u8::try_from(index).unwrap_or(u8::MAX)
}
