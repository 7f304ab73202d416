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

    /// Whether it remembers anything at all (capacity above 0): callers skip copying a failed
    /// scene for a memory that would drop it.
    pub fn is_on(&self) -> bool {
        self.capacity > 0
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

    /// The remembered scenes, oldest first (for checkpoints).
    pub fn scenes(&self) -> impl Iterator<Item = &Scenario> {
        self.failed.iter()
    }

    /// Replaces what is remembered with `scenes`, oldest first, keeping at most the capacity
    /// (the newest), as restoring a checkpoint does.
    pub fn restore(&mut self, scenes: Vec<Scenario>) {
        let skip = scenes.len().saturating_sub(self.capacity);
        self.failed = scenes.into_iter().skip(skip).collect();
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
        // Probability 0 draws nothing, so such a memory leaves the caller's scene stream as it
        // would be without one.
        if self.failed.is_empty()
            || self.resample_probability <= 0.0
            || !rng.random_bool(self.resample_probability)
        {
            return None;
        }
        let index = rng.random_range(0..self.failed.len());
        self.failed.swap_remove_back(index)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generate::{generate_many, SceneKind};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn scenes(n: usize) -> Vec<Scenario> {
        generate_many(
            crate::generate::SceneRobot::shipped(),
            SceneKind::Complex,
            &mut ChaCha8Rng::seed_from_u64(3),
            n,
        )
    }

    #[test]
    fn it_forgets_the_oldest_and_hands_each_failure_out_once() {
        let mut memory = FailureMemory::new(2, 1.0);
        let s = scenes(3);
        for scene in &s {
            memory.record_failure(scene.clone());
        }
        let names: Vec<&str> = memory.scenes().map(|x| x.name.as_str()).collect();
        assert_eq!(names, [s[1].name.as_str(), s[2].name.as_str()]);
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let a = memory.take(&mut rng).unwrap();
        let b = memory.take(&mut rng).unwrap();
        assert_ne!(a.name, b.name);
        assert!(
            memory.take(&mut rng).is_none(),
            "empty: a fresh scene is due"
        );
        memory.restore(s.clone());
        assert_eq!(
            memory.len(),
            2,
            "restoring keeps the newest up to the capacity"
        );
    }

    #[test]
    fn probability_zero_and_capacity_zero_draw_nothing() {
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let before = rng.get_word_pos();
        let mut never = FailureMemory::new(4, 0.0);
        never.record_failure(scenes(1).remove(0));
        assert!(never.take(&mut rng).is_none());
        let mut none = FailureMemory::new(0, 1.0);
        assert!(!none.is_on() && never.is_on());
        none.record_failure(scenes(1).remove(0));
        assert!(none.is_empty());
        assert!(none.take(&mut rng).is_none());
        assert_eq!(rng.get_word_pos(), before);
    }
}
