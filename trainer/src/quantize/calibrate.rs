//! Activation ranges from calibration observations.
//!
//! Every tensor that gets its own int8 quantization (the height map, each state feature, each
//! layer's output) has a [`RangeObserver`]. It keeps the exact min and max, and a uniform
//! reservoir sample of the values so that percentile ranges (which ignore rare outliers) can be
//! computed without keeping every value of every rollout.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::network_f32::{NetworkF32, Trace};

/// How a range is chosen from the observations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RangeMethod {
    /// The observed minimum and maximum.
    MinMax,
    /// The given lower and upper percentiles of the sampled values, e.g. `0.01` and `99.99`.
    Percentile {
        /// Lower percentile, 0..100.
        low: f32,
        /// Upper percentile, 0..100.
        high: f32,
    },
}

/// Values kept per tensor for percentiles.
const RESERVOIR: usize = 65_536;

/// Min, max and a reservoir sample of one tensor's values.
#[derive(Clone, Debug)]
pub struct RangeObserver {
    min: f32,
    max: f32,
    seen: u64,
    sample: Vec<f32>,
    rng: ChaCha8Rng,
}

impl RangeObserver {
    /// An observer that has seen nothing (its range is then `[0, 0]`).
    pub fn new(seed: u64) -> RangeObserver {
        RangeObserver {
            min: f32::INFINITY,
            max: f32::NEG_INFINITY,
            seen: 0,
            sample: Vec::new(),
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Records values (non-finite ones are ignored: they say nothing about a range).
    pub fn observe(&mut self, values: &[f32]) {
        for &value in values.iter().filter(|v| v.is_finite()) {
            self.min = self.min.min(value);
            self.max = self.max.max(value);
            self.seen += 1;
            // Algorithm R: the k-th value replaces a random slot with probability N / k.
            if self.sample.len() < RESERVOIR {
                self.sample.push(value);
            } else {
                let slot = self.rng.random_range(0..self.seen);
                if let Some(kept) = self.sample.get_mut(slot as usize) {
                    *kept = value;
                }
            }
        }
    }

    /// The range by `method`, always containing 0 (so that real 0, the padding and the ReLU
    /// floor, is exactly representable).
    pub fn range(&self, method: RangeMethod) -> (f32, f32) {
        if self.seen == 0 {
            return (0.0, 0.0);
        }
        let (low, high) = match method {
            RangeMethod::MinMax => (self.min, self.max),
            RangeMethod::Percentile { low, high } => {
                let mut sorted = self.sample.clone();
                sorted.sort_by(f32::total_cmp);
                let at = |p: f32| {
                    let index = ((p / 100.0).clamp(0.0, 1.0) * (sorted.len() - 1) as f32).round();
                    sorted[index as usize]
                };
                (at(low), at(high))
            }
        };
        (low.min(0.0), high.max(0.0))
    }
}

/// Which values decide the action head's output range (with int16 logits, format version 2,
/// the largest magnitude of these values sets the symmetric scale; with int8 logits, version 1,
/// their min and max set the affine range).
///
/// The choice mattered for int8 logits, whose 255 steps were coarse enough for rounding to
/// flip near ties (1.1% of head decisions on the baseline policy): `Contenders` gave a finer
/// step and raised agreement. With int16 logits the step is at least 64 times finer either
/// way and both choices measure the same on the baseline policy (docs/results.md, "Quantization"), so
/// the default is `AllLogits`, which keeps every logit unclamped (sampling probabilities
/// stay right too).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ActionRange {
    /// Every logit: the quantized logits track all float logits (needed when probabilities
    /// are used, e.g. sampling).
    #[default]
    AllLogits,
    /// Only each head's two largest logits, the contenders for its argmax. The robot acts on
    /// the argmax alone, and a logit below every head's runner-up never decides it, so the
    /// range can drop the long tail of very negative logits: a finer step, fewer near-ties
    /// flipped by rounding. Clamped low logits change sampling probabilities of choices that
    /// were already improbable.
    Contenders,
}

/// Observers for every quantized tensor of a network.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// Height map (all cells share one quantization).
    pub height: RangeObserver,
    /// Each state feature.
    pub state: Vec<RangeObserver>,
    /// Each conv layer's output.
    pub convs: Vec<RangeObserver>,
    /// Each hidden dense layer's output.
    pub hidden: Vec<RangeObserver>,
    /// Action logits.
    pub action: RangeObserver,
    /// Each head's largest and second-largest logit (see [`ActionRange::Contenders`]).
    pub action_contenders: RangeObserver,
    /// Which observer sets the action head's output range.
    pub action_range: ActionRange,
    /// Value.
    pub value: RangeObserver,
    /// Observations seen.
    pub count: usize,
}

impl Calibration {
    /// Empty observers shaped for `network`.
    pub fn new(network: &NetworkF32) -> Calibration {
        let mut seed = 0u64;
        let mut next = || {
            seed += 1;
            RangeObserver::new(seed)
        };
        Calibration {
            height: next(),
            state: (0..network.arch.state_len).map(|_| next()).collect(),
            convs: network.convs.iter().map(|_| next()).collect(),
            hidden: network.hidden.iter().map(|_| next()).collect(),
            action: next(),
            value: next(),
            action_contenders: next(),
            action_range: ActionRange::default(),
            count: 0,
        }
    }

    /// Records every tensor of one forward pass.
    pub fn observe(&mut self, trace: &Trace) {
        self.height.observe(&trace.height_m);
        for (observer, &value) in self.state.iter_mut().zip(&trace.state) {
            observer.observe(&[value]);
        }
        for (observer, values) in self.convs.iter_mut().zip(&trace.convs) {
            observer.observe(values);
        }
        for (observer, values) in self.hidden.iter_mut().zip(&trace.hidden) {
            observer.observe(values);
        }
        self.action.observe(&trace.action_logits);
        for head in trace
            .action_logits
            .chunks_exact(wheelleg_runtime::action::CHOICES)
        {
            let mut sorted = head.to_vec();
            sorted.sort_by(|a, b| b.total_cmp(a));
            self.action_contenders
                .observe(&sorted[..2.min(sorted.len())]);
        }
        if let Some(value) = trace.value {
            self.value.observe(&[value]);
        }
        self.count += 1;
    }

    /// Runs `network` on each observation (height map in metres, state) and records it.
    pub fn from_observations<'a>(
        network: &NetworkF32,
        observations: impl IntoIterator<Item = (&'a [f32], &'a [f32])>,
    ) -> Calibration {
        let mut calibration = Calibration::new(network);
        for (height_m, state) in observations {
            calibration.observe(&network.trace(height_m, state));
        }
        calibration
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_contain_zero_and_percentiles_drop_outliers() {
        let mut observer = RangeObserver::new(7);
        let values: Vec<f32> = (1..=1000).map(|i| i as f32 / 1000.0).collect();
        observer.observe(&values);
        observer.observe(&[50.0, f32::NAN]);
        assert_eq!(observer.range(RangeMethod::MinMax), (0.0, 50.0));
        let (low, high) = observer.range(RangeMethod::Percentile {
            low: 0.0,
            high: 99.0,
        });
        assert_eq!(low, 0.0);
        assert!((high - 0.99).abs() < 0.01, "{high}");
        assert_eq!(RangeObserver::new(1).range(RangeMethod::MinMax), (0.0, 0.0));
    }
}
