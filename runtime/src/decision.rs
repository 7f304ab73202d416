//! From the policy's five heads to one action, without getting stuck.
//!
//! Taking each head's most probable choice is a deterministic rule, and a deterministic rule
//! loops: when the chosen action is refused (it would collide, or the legs cannot reach the
//! pose), the robot's state and so its observation stay exactly as they were, and the same
//! observation gives the same action again until the episode's step limit. A sampling policy
//! escapes by chance; on held-out complex scenes the baseline reaches 88.5% sampled and only
//! 70.3% by per-head argmax (docs/results.md, "Decision rule").
//!
//! [`Decider`] keeps the rule deterministic and removes the loop: it picks the most probable
//! *joint* action that has not already been refused in the current state. The memory is a
//! 243-bit set (one bit per joint action, 32 bytes), cleared whenever the state changes, so it
//! never fills and never allocates.

use crate::action::{Action, CHOICES, COUNT, DIMS};

/// Words of the refused-action bit set.
const WORDS: usize = COUNT.div_ceil(32);

/// The most probable joint action not yet refused in the current state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Decider {
    refused: [u32; WORDS],
}

impl Decider {
    /// A decider with nothing refused.
    pub const fn new() -> Decider {
        Decider {
            refused: [0; WORDS],
        }
    }

    /// The joint action with the highest sum of per-head logits (the most probable joint
    /// action: each head's log-normaliser is common to all joint actions) among those not
    /// refused in the current state. Ties go to the lowest joint index, which is each head's
    /// first maximum, as a per-head argmax takes it. Logits may be raw logits or
    /// log-probabilities, in head order `Dim::ALL` and choice order `Step::ALL`. A NaN logit
    /// never wins; if every score is NaN, the first unrefused action is taken.
    pub fn choose<L: Copy + Into<f32>>(&self, logits: &[L; DIMS * CHOICES]) -> Action {
        let mut best: Option<(usize, f32)> = None;
        for index in 0..COUNT {
            if self.is_refused_index(index) {
                continue;
            }
            let score = joint_score(logits, index);
            let better = match best {
                None => true,
                Some((_, best_score)) => {
                    score > best_score || (best_score.is_nan() && !score.is_nan())
                }
            };
            if better {
                best = Some((index, score));
            }
        }
        // With at most 242 refusals (see `record`) some action is always left.
        best.and_then(|(index, _)| Action::from_index(index))
            .unwrap_or(Action::IDLE)
    }

    /// Tells the decider what became of `action`: `state_changed` is false when the robot is
    /// exactly where it was (the action was refused). Idle never changes the state, whatever
    /// the caller says, so it is remembered like a refusal: repeating it would loop just the
    /// same. A change of state clears the memory: in a new state every action deserves a fresh
    /// try. If every joint action has been refused in one state, the memory starts over rather
    /// than leave nothing to choose.
    pub fn record(&mut self, action: Action, state_changed: bool) {
        if state_changed && action != Action::IDLE {
            self.reset();
            return;
        }
        let index = action.index();
        if let Some(word) = self.refused.get_mut(index / 32) {
            *word |= 1 << (index % 32);
        }
        if self.refused_count() >= COUNT {
            self.reset();
        }
    }

    /// Forgets every refusal (a new episode, or a state change the caller knows of).
    pub fn reset(&mut self) {
        self.refused = [0; WORDS];
    }

    /// Whether `action` has been refused in the current state.
    pub fn is_refused(&self, action: Action) -> bool {
        self.is_refused_index(action.index())
    }

    /// How many joint actions have been refused in the current state.
    pub fn refused_count(&self) -> usize {
        self.refused.iter().map(|w| w.count_ones() as usize).sum()
    }

    fn is_refused_index(&self, index: usize) -> bool {
        self.refused
            .get(index / 32)
            .is_some_and(|word| word & (1 << (index % 32)) != 0)
    }
}

/// Sum of the chosen logit of each head for joint action `index`.
fn joint_score<L: Copy + Into<f32>>(logits: &[L; DIMS * CHOICES], index: usize) -> f32 {
    let mut rest = index;
    let mut score = 0.0;
    // Base-3 digits, last head least significant (as `Action::from_index`).
    for head in (0..DIMS).rev() {
        let choice = rest % CHOICES;
        rest /= CHOICES;
        score += logits
            .get(head * CHOICES + choice)
            .map_or(f32::NAN, |&l| l.into());
    }
    score
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::Step;

    fn argmax_per_head(logits: &[f32; DIMS * CHOICES]) -> Action {
        let mut indices = [0usize; DIMS];
        for (h, index) in indices.iter_mut().enumerate() {
            for c in 1..CHOICES {
                if logits[h * CHOICES + c] > logits[h * CHOICES + *index] {
                    *index = c;
                }
            }
        }
        Action::from_head_indices(indices).unwrap()
    }

    #[test]
    fn with_nothing_refused_it_is_the_per_head_argmax() {
        let logits = [
            0.1, 0.5, 0.2, 1.0, -1.0, 0.0, 0.3, 0.3, 0.1, -2.0, -1.0, -3.0, 0.0, 0.0, 0.0,
        ];
        assert_eq!(Decider::new().choose(&logits), argmax_per_head(&logits));
    }

    #[test]
    fn a_refused_action_is_replaced_by_the_next_most_probable() {
        // Move x: forward clearly best, then idle; other heads: idle clearly best.
        let mut logits = [0.0f32; DIMS * CHOICES];
        logits[0] = -5.0;
        logits[1] = 1.0;
        logits[2] = 2.0;
        for h in 1..DIMS {
            logits[h * CHOICES + 1] = 3.0;
        }
        let mut decider = Decider::new();
        let first = decider.choose(&logits);
        assert_eq!(first.move_x, Step::Plus);
        decider.record(first, false);
        let second = decider.choose(&logits);
        assert_ne!(second, first);
        // Next best: keep every head at its best but switch move x to idle (loses 1.0), rather
        // than any other head (loses at least 3.0).
        assert_eq!(second.move_x, Step::Zero);
        assert_eq!(second.yaw, Step::Zero);
        decider.record(second, false);
        assert_eq!(decider.refused_count(), 2);
        // The second choice was idle; idle never clears the memory, even when the caller
        // reports a change.
        assert_eq!(second, Action::IDLE);
        decider.record(Action::IDLE, true);
        assert!(decider.is_refused(Action::IDLE));
        assert_eq!(decider.refused_count(), 2);
        // Once the state changes, the best action is allowed again.
        decider.record(first, true);
        assert_eq!(decider.choose(&logits), first);
    }

    #[test]
    fn refusing_everything_starts_over_instead_of_running_dry() {
        let logits = [0i16; DIMS * CHOICES];
        let mut decider = Decider::new();
        let mut seen = [false; COUNT];
        for _ in 0..COUNT {
            let action = decider.choose(&logits);
            assert!(!seen[action.index()], "an action was chosen twice");
            seen[action.index()] = true;
            decider.record(action, false);
        }
        assert_eq!(decider.refused_count(), 0, "the full set starts over");
        assert_eq!(decider.choose(&logits), Action::from_index(0).unwrap());
    }

    #[test]
    fn nan_logits_never_panic_and_never_win() {
        let mut logits = [0.0f32; DIMS * CHOICES];
        logits[0] = f32::NAN;
        let action = Decider::new().choose(&logits);
        assert_ne!(action.move_x, Step::Minus);
        let all_nan = [f32::NAN; DIMS * CHOICES];
        assert_eq!(
            Decider::new().choose(&all_nan),
            Action::from_index(0).unwrap()
        );
    }
}
