//! The reward, as the paper's Eq. (reward): r = r_step + r_progress + r_invalid.

/// Paid every step: pushes towards short paths.
pub const STEP_PENALTY: f32 = -0.1;
/// Paid when the action was invalid (collision, impossible leg pose, out of bounds) and undone.
pub const INVALID_PENALTY: f32 = -0.1;

/// The three terms of one step's reward.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RewardTerms {
    /// The fixed time penalty.
    pub step: f32,
    /// Distance to the target before the step minus after it.
    pub progress: f32,
    /// The invalid-action penalty, or 0.
    pub invalid: f32,
}

impl RewardTerms {
    /// The terms for one step, with the paper's invalid-action penalty.
    pub fn new(distance_before_m: f32, distance_after_m: f32, invalid: bool) -> Self {
        Self::with_invalid_reward(
            distance_before_m,
            distance_after_m,
            invalid,
            INVALID_PENALTY,
        )
    }

    /// The terms for one step, paying `invalid_reward` for an undone action.
    pub fn with_invalid_reward(
        distance_before_m: f32,
        distance_after_m: f32,
        invalid: bool,
        invalid_reward: f32,
    ) -> Self {
        RewardTerms {
            step: STEP_PENALTY,
            progress: distance_before_m - distance_after_m,
            invalid: if invalid { invalid_reward } else { 0.0 },
        }
    }

    /// The reward.
    pub fn total(&self) -> f32 {
        self.step + self.progress + self.invalid
    }
}
