//! From the policy's five heads to one action, without getting stuck.
//!
//! Taking each head's most probable choice is a deterministic rule in a deterministic world, and
//! such a pair loops whenever the robot meets an observation it has already acted on: the same
//! observation gives the same action, which leads the same way again. Two loops are common:
//! - a refused action (it would collide, or the legs cannot reach the pose) leaves the robot
//!   where it was, so the observation and the action repeat until the episode's step limit;
//! - a cycle of moves (forward, back, forward...) near a target the policy cannot quite reach.
//!
//! A sampling policy escapes by chance; on held-out complex scenes the baseline reaches 88.5%
//! sampled and only 70.3% by per-head argmax (docs/results.md, "Decision rule").
//!
//! [`Decider`] keeps the rule deterministic and removes both loops: for each of the last
//! `STATES` distinct observations it remembers which joint actions it already took there (a
//! 243-bit set, 32 bytes), and it picks the most probable joint action not yet taken at the
//! current observation. A fresh observation has nothing remembered, so there the rule is the
//! per-head argmax. Observations are told apart by an [`ObservationKey`], a hash of exactly
//! what the int8 policy reads (heights and state in millimetres), so no odometry is needed and
//! the float and int8 paths key alike. Memory is fixed at compile time (`STATES` x 40 bytes;
//! the default 128 covers a 100-step episode); the oldest observation is forgotten first.

use crate::action::{Action, CHOICES, COUNT, DIMS};

/// Words of one observation's taken-action bit set.
const WORDS: usize = COUNT.div_ceil(32);

/// Observations remembered by default: more than the decisions of one 100-step episode.
pub const DEFAULT_STATES: usize = 128;

/// Identifies an observation: a 64-bit FNV-1a hash of the height map (i16 millimetres) and the
/// state (i32 millimetres), the integer inputs of the runtime's policy. Two observations that
/// differ anywhere get different keys except with probability about 2^-64 (and then the robot
/// merely avoids an action it took elsewhere).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ObservationKey(pub u64);

/// FNV-1a, 64-bit: written here because it is ten lines, needs no allocation and must give the
/// same key on the robot and the host (a `core::hash::Hasher` does not promise a stable value).
const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

fn fnv(mut hash: u64, bytes: &[u8]) -> u64 {
    for &byte in bytes {
        hash ^= u64::from(byte);
        hash = hash.wrapping_mul(FNV_PRIME);
    }
    hash
}

impl ObservationKey {
    /// The key of the runtime's integer inputs (heights then state, millimetres).
    pub fn of_mm(height_mm: &[i16], state_mm: &[i32]) -> ObservationKey {
        let mut hash = FNV_OFFSET;
        for h in height_mm {
            hash = fnv(hash, &h.to_le_bytes());
        }
        for s in state_mm {
            hash = fnv(hash, &s.to_le_bytes());
        }
        ObservationKey(hash)
    }

    /// The key of an observation in metres, rounded to millimetres half away from zero as the
    /// robot's inputs are (saturating, so absurd values cannot wrap), so a float policy on the
    /// host and the int8 policy on the robot key the same observation alike.
    pub fn of_metres(height_m: &[f32], state_m: &[f32]) -> ObservationKey {
        let mut hash = FNV_OFFSET;
        for h in height_m {
            hash = fnv(hash, &(libm::roundf(h * 1000.0) as i16).to_le_bytes());
        }
        for s in state_m {
            hash = fnv(hash, &(libm::roundf(s * 1000.0) as i32).to_le_bytes());
        }
        ObservationKey(hash)
    }
}

/// The most probable joint action not yet taken at the current observation. Not `Copy`: at
/// the default capacity it is 5 KB.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Decider<const STATES: usize = DEFAULT_STATES> {
    keys: [ObservationKey; STATES],
    taken: [[u32; WORDS]; STATES],
    /// Slots in use (`keys[..len]`).
    len: usize,
    /// The slot to overwrite next once all are in use: the oldest observation.
    oldest: usize,
}

impl<const STATES: usize> Default for Decider<STATES> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const STATES: usize> Decider<STATES> {
    /// A decider that remembers nothing yet.
    pub const fn new() -> Decider<STATES> {
        Decider {
            keys: [ObservationKey(0); STATES],
            taken: [[0; WORDS]; STATES],
            len: 0,
            oldest: 0,
        }
    }

    /// Picks the action for observation `key`, and remembers it as taken there: the joint
    /// action with the highest sum of per-head logits (the most probable joint action: each
    /// head's log-normaliser is common to all joint actions) among those not yet taken at this
    /// observation. Ties go to the lowest joint index, which is each head's first maximum, as a
    /// per-head argmax takes it. Logits may be raw logits or log-probabilities, in head order
    /// `Dim::ALL` and choice order `Step::ALL`. A NaN logit never wins; if every score is NaN,
    /// the first untaken action is taken. Once all 243 actions have been taken at one
    /// observation, its memory starts over rather than leave nothing to choose.
    pub fn choose<L: Copy + Into<f32>>(
        &mut self,
        key: ObservationKey,
        logits: &[L; DIMS * CHOICES],
    ) -> Action {
        self.choose_checked(key, logits, 0, |_, _| true).action
    }

    /// [`Decider::choose`] among the actions a check accepts (a look-ahead check such as
    /// [`crate::guard::CollisionGuard`]), with `levels` checks from strict to lenient: the most
    /// probable joint action not yet taken at this observation that `allowed(0, action)`
    /// passes; if it refuses every untaken action, the most probable that `allowed(1, action)`
    /// passes; and so on. `allowed` is asked lazily, best candidate first, so a policy that is
    /// right costs one check. When every level refuses every untaken action, the plain choice
    /// is taken anyway (a check that is wrong must not stop the robot for good), and the
    /// returned [`Checked::level`] is `None`.
    pub fn choose_checked<L: Copy + Into<f32>>(
        &mut self,
        key: ObservationKey,
        logits: &[L; DIMS * CHOICES],
        levels: usize,
        mut allowed: impl FnMut(usize, Action) -> bool,
    ) -> Checked {
        let decided = self.choose_checked_in_time(key, logits, levels, |level, action| {
            Some(allowed(level, action))
        });
        // `allowed` never runs out of time, so a decision always comes; the fallback only
        // keeps the types honest.
        decided.unwrap_or(Checked {
            action: Action::IDLE,
            level: None,
            checks: 0,
        })
    }

    /// [`Decider::choose_checked`] with a deadline: `allowed` answers `None` once the time
    /// for this decision is up, and the decision is abandoned (`None`) with nothing
    /// remembered, so that the same observation decided again later meets the same
    /// candidates. A controller bounds its decisions' time this way: each candidate costs
    /// one check, and a check refused or passed before the deadline counts as usual.
    pub fn choose_checked_in_time<L: Copy + Into<f32>>(
        &mut self,
        key: ObservationKey,
        logits: &[L; DIMS * CHOICES],
        levels: usize,
        mut allowed: impl FnMut(usize, Action) -> Option<bool>,
    ) -> Option<Checked> {
        let mut checks = 0;
        let taken = match self.find(key).and_then(|slot| self.taken.get(slot)) {
            Some(taken) if count(taken) < COUNT => *taken,
            _ => [0; WORDS],
        };
        for level in 0..levels {
            let mut excluded = taken;
            while count(&excluded) < COUNT {
                let candidate = best_untaken(&excluded, logits);
                checks += 1;
                if allowed(level, candidate)? {
                    self.remember_taken(key, candidate);
                    return Some(Checked {
                        action: candidate,
                        level: Some(level),
                        checks,
                    });
                }
                let index = candidate.index();
                if let Some(word) = excluded.get_mut(index / 32) {
                    *word |= 1 << (index % 32);
                }
            }
        }
        let action = best_untaken(&taken, logits);
        self.remember_taken(key, action);
        Some(Checked {
            action,
            level: None,
            checks,
        })
    }

    /// Remembers `action` as taken at observation `key`, as if [`Decider::choose`] had chosen
    /// it there: the observation's memory is made if new (evicting the oldest) and starts over
    /// first if every action was taken. For layers above the rule (a look-ahead) that take an
    /// action of their own choosing.
    pub fn remember_taken(&mut self, key: ObservationKey, action: Action) {
        let index = action.index();
        if let Some(taken) = self.slot(key) {
            if count(taken) >= COUNT {
                *taken = [0; WORDS];
            }
            if let Some(word) = taken.get_mut(index / 32) {
                *word |= 1 << (index % 32);
            }
        }
    }

    /// Whether `action` has already been taken at observation `key` (as far as the decider
    /// still remembers).
    pub fn was_taken(&self, key: ObservationKey, action: Action) -> bool {
        let index = action.index();
        self.find(key)
            .and_then(|slot| self.taken.get(slot))
            .and_then(|taken| taken.get(index / 32))
            .is_some_and(|word| word & (1 << (index % 32)) != 0)
    }

    /// How many joint actions have been taken at observation `key`.
    pub fn taken_count(&self, key: ObservationKey) -> usize {
        self.find(key)
            .and_then(|slot| self.taken.get(slot))
            .map_or(0, count)
    }

    /// How many distinct observations are remembered (at most `STATES`).
    pub fn remembered(&self) -> usize {
        self.len
    }

    /// Forgets everything (a new episode, or a world that changed).
    pub fn reset(&mut self) {
        self.len = 0;
        self.oldest = 0;
    }

    fn find(&self, key: ObservationKey) -> Option<usize> {
        self.keys.get(..self.len)?.iter().position(|k| *k == key)
    }

    /// The taken-set of `key`, made (empty) if the observation is new, evicting the oldest
    /// remembered observation when all slots are in use. `None` only when `STATES` is 0.
    fn slot(&mut self, key: ObservationKey) -> Option<&mut [u32; WORDS]> {
        let slot = match self.find(key) {
            Some(slot) => slot,
            None => {
                let slot = if self.len < STATES {
                    self.len += 1;
                    self.len - 1
                } else {
                    let slot = self.oldest;
                    self.oldest = (self.oldest + 1) % STATES.max(1);
                    slot
                };
                *self.keys.get_mut(slot)? = key;
                *self.taken.get_mut(slot)? = [0; WORDS];
                slot
            }
        };
        self.taken.get_mut(slot)
    }
}

/// What [`Decider::choose_checked`] decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Checked {
    /// The action to take.
    pub action: Action,
    /// The strictest check level that passed it; `None`: every level refused every untaken
    /// action, and this is the plain choice.
    pub level: Option<usize>,
    /// How many candidates were checked.
    pub checks: usize,
}

fn count(taken: &[u32; WORDS]) -> usize {
    taken.iter().map(|w| w.count_ones() as usize).sum()
}

fn best_untaken<L: Copy + Into<f32>>(taken: &[u32; WORDS], logits: &[L; DIMS * CHOICES]) -> Action {
    let mut best: Option<(usize, f32)> = None;
    for index in 0..COUNT {
        let is_taken = taken
            .get(index / 32)
            .is_some_and(|word| word & (1 << (index % 32)) != 0);
        if is_taken {
            continue;
        }
        let score = joint_score(logits, index);
        let better = match best {
            None => true,
            Some((_, best_score)) => score > best_score || (best_score.is_nan() && !score.is_nan()),
        };
        if better {
            best = Some((index, score));
        }
    }
    // `choose` clears a full set first, so some action is always left.
    best.and_then(|(index, _)| Action::from_index(index))
        .unwrap_or(Action::IDLE)
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
pub(crate) mod tests;
