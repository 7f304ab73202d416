//! How often the int8 policy takes the float policy's greedy action (the model card's agreement
//! figure), per action dimension, on observations the calibration did not see.

use super::Int8Policy;
use crate::error::TrainError;
use crate::network_f32::NetworkF32;
use serde::Serialize;
use wheelleg_runtime::action::{CHOICES, DIMS};

/// Agreement of greedy choices on a set of observations.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Agreement {
    /// Observations compared.
    pub observations: usize,
    /// Per action dimension (in `Dim::ALL` order: x, y, yaw, height, width), the fraction of
    /// observations where both networks chose the same step.
    pub per_dimension: [f32; DIMS],
    /// Fraction of observations where all five dimensions agree (the whole action).
    pub whole_action: f32,
    /// Mean absolute difference between float and dequantized int8 logits.
    pub mean_logit_error: f32,
}

impl Agreement {
    /// The worst dimension's agreement.
    pub fn worst_dimension(&self) -> f32 {
        self.per_dimension.iter().copied().fold(1.0, f32::min)
    }

    /// Names of the dimensions in [`Agreement::per_dimension`] order.
    pub const DIMENSION_NAMES: [&'static str; DIMS] =
        ["move x", "move y", "rotate", "height", "width"];
}

/// First index of the largest value: the same tie rule as the runtime's greedy action.
fn argmax(values: &[f32]) -> usize {
    let mut best = 0;
    for (i, &v) in values.iter().enumerate() {
        if values.get(best).is_some_and(|&b| v > b) {
            best = i;
        }
    }
    best
}

/// Compares `float` (the plain f32 reference) with `int8` (the runtime) on `observations`
/// (height map in metres, state).
pub fn agreement(
    float: &NetworkF32,
    int8: &Int8Policy<'_>,
    observations: &[crate::evaluate::RecordedObservation],
) -> Result<Agreement, TrainError> {
    let mut same = [0usize; DIMS];
    let mut whole = 0usize;
    let mut error_sum = 0.0f64;
    for (height_m, state) in observations {
        let (float_logits, _) = float.forward(height_m, state);
        let int8_logits = int8
            .evaluate_m(height_m, state)
            .map_err(TrainError::Infer)?
            .action_logits_f32();
        let mut all = true;
        for (dim, (f, q)) in float_logits
            .chunks_exact(CHOICES)
            .zip(int8_logits.chunks_exact(CHOICES))
            .enumerate()
        {
            if argmax(f) == argmax(q) {
                same[dim] += 1;
            } else {
                all = false;
            }
        }
        whole += usize::from(all);
        error_sum += float_logits
            .iter()
            .zip(&int8_logits)
            .map(|(f, q)| f64::from((f - q).abs()))
            .sum::<f64>();
    }
    let n = observations.len().max(1) as f32;
    Ok(Agreement {
        observations: observations.len(),
        per_dimension: same.map(|s| s as f32 / n),
        whole_action: whole as f32 / n,
        mean_logit_error: (error_sum / (n as f64 * (DIMS * CHOICES) as f64)) as f32,
    })
}
