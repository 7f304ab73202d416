//! The memory of failed configurations (the paper: "we save the configuration which our agent
//! failed to find a solution and assign a probability to re-sample them").

use crate::scenario::Scenario;
use rand::Rng;
use std::collections::VecDeque;

/// Scenes the policy failed, re-offered with a set probability.
#[derive(Clone, Debug)]
pub struct FailureMemory {
    capacity: usize,
    resample_probability: f64,
    failed: VecDeque<Scenario>,
}

impl FailureMemory {
    /// A memory of at most `capacity` scenes (the oldest are forgotten first), re-sampled with
    /// probability `resample_probability` (clamped to [0, 1]).
    pub fn new(capacity: usize, resample_probability: f64) -> Self {
        FailureMemory {
            capacity,
            resample_probability: resample_probability.clamp(0.0, 1.0),
            failed: VecDeque::with_capacity(capacity),
        }
    }

    /// Remembers a scene the policy failed.
    pub fn record_failure(&mut self, scenario: Scenario) {
        if self.capacity == 0 {
            return;
        }
        if self.failed.len() == self.capacity {
            self.failed.pop_front();
        }
        self.failed.push_back(scenario);
    }

    /// Number of remembered scenes.
    pub fn len(&self) -> usize {
        self.failed.len()
    }

    /// Whether nothing is remembered.
    pub fn is_empty(&self) -> bool {
        self.failed.is_empty()
    }

    /// With the resample probability, takes out a remembered failure to train on again (it
    /// returns to the memory only if failed again); otherwise `None`, and the caller draws a
    /// fresh scene.
    pub fn take(&mut self, rng: &mut impl Rng) -> Option<Scenario> {
        if self.failed.is_empty() || !rng.random_bool(self.resample_probability) {
            return None;
        }
        let index = rng.random_range(0..self.failed.len());
        self.failed.swap_remove_back(index)
    }
}
