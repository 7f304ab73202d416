//! The robot's rule at one decision: the untried rule, the collision guard where one checks the
//! actions, the arrival rule where it is on. What the controller firmware runs; the host's
//! layers ([`crate::lookahead`]) ask it for its candidates in order.

use wheelleg_runtime::action::{Action, CHOICES, DIMS};
use wheelleg_runtime::arrival::Arrival;
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_runtime::guard::{CollisionGuard, HeightMapRef};
use wheelleg_runtime::leg::LegConfig;

/// The collision guard as it stands at one observation.
#[derive(Clone, Copy, Debug)]
pub struct GuardAt<'a> {
    /// The guard.
    pub guard: &'a CollisionGuard,
    /// The map it reads.
    pub map: HeightMapRef<'a>,
    /// The robot's legs now, which it checks a step from.
    pub legs: LegConfig,
}

/// The robot's rule as it stands at one observation.
#[derive(Clone, Copy, Debug)]
pub struct RobotRule<'a> {
    /// The guard; none: actions unchecked.
    pub guard: Option<GuardAt<'a>>,
    /// The arrival rule at this observation; none: off.
    pub arrival: Option<Arrival>,
}

impl RobotRule<'_> {
    /// The rule alone: no guard, no arrival.
    pub fn untried() -> RobotRule<'static> {
        RobotRule {
            guard: None,
            arrival: None,
        }
    }

    /// The action to take at `key` given the policy's `logits`, marked taken in `decider`.
    pub fn choose<L: Copy + Into<f32>>(
        &self,
        decider: &mut Decider,
        key: ObservationKey,
        logits: &[L; DIMS * CHOICES],
    ) -> Action {
        match (self.guard, &self.arrival) {
            (Some(at), arrival) => {
                at.guard
                    .choose(decider, key, logits, at.map, at.legs, arrival.as_ref())
                    .action
            }
            (None, Some(arrival)) => arrival.choose(decider, key, logits).action,
            (None, None) => decider.choose(key, logits),
        }
    }

    /// Whether the guard (if any) lets `action` be sent now.
    pub fn allows(&self, action: Action) -> bool {
        self.guard
            .is_none_or(|at| at.guard.check(at.map, at.legs, action).is_ok())
    }
}

/// The candidate actions at one decision, in the rule's order of preference: `decide` is the
/// robot's rule applied to a decider; called on a copy of `decider` again and again, it names
/// the rule's own action and then what it would fall back to, each marked taken in the copy.
/// At most `count`, all distinct.
pub fn candidates(
    decider: &Decider,
    count: usize,
    mut decide: impl FnMut(&mut Decider) -> Action,
) -> Vec<Action> {
    let mut copy = decider.clone();
    let mut found: Vec<Action> = Vec::with_capacity(count);
    // The rule may repeat itself once every action was taken at an observation (its memory
    // starts over); a bounded number of calls keeps that from looping.
    for _ in 0..count.saturating_mul(2) {
        if found.len() >= count {
            break;
        }
        let action = decide(&mut copy);
        if !found.contains(&action) {
            found.push(action);
        }
    }
    found
}

/// The rule's own action when there is nothing to weigh: fewer than two candidates, or the
/// first (the rule's own) already reaches the target under `arrival`. `None`: weigh them.
pub fn settled(found: &[Action], arrival: Option<&Arrival>) -> Option<Action> {
    let first = found.first().copied().unwrap_or_default();
    let arrives = arrival.is_some_and(|a| a.reached_by(first));
    (found.len() < 2 || arrives).then_some(first)
}

/// Marks `action` taken at `key` in `decider`, as if its rule had chosen it.
pub fn mark_taken(decider: &mut Decider, key: ObservationKey, action: Action) {
    if decider.was_taken(key, action) {
        return;
    }
    decider.remember_taken(key, action);
}

#[cfg(test)]
mod tests {
    use super::*;
    use wheelleg_runtime::action::Step;

    #[test]
    fn one_candidate_or_an_arriving_first_needs_no_weighing() {
        let ahead = Action {
            move_x: Step::Plus,
            ..Action::IDLE
        };
        let near = Arrival::new(
            nalgebra::Vector2::new(0.05, 0.0),
            0.05,
            &wheelleg_runtime::robot::Robot::WHEELLEG.actions,
        );
        let far = Arrival::new(
            nalgebra::Vector2::new(0.5, 0.0),
            0.05,
            &wheelleg_runtime::robot::Robot::WHEELLEG.actions,
        );
        assert_eq!(settled(&[ahead], None), Some(ahead));
        assert_eq!(settled(&[ahead, Action::IDLE], Some(&near)), Some(ahead));
        assert_eq!(settled(&[ahead, Action::IDLE], Some(&far)), None);
        assert_eq!(settled(&[ahead, Action::IDLE], None), None);
    }

    #[test]
    fn candidates_are_the_rules_choices_in_order_and_distinct() {
        let mut logits = [0.0f32; DIMS * CHOICES];
        // Head move x prefers Plus, then Zero; everything else Zero.
        for dim in 0..DIMS {
            logits[dim * CHOICES + 1] = 1.0;
        }
        logits[2] = 2.0;
        let key = ObservationKey(7);
        let decider: Decider = Decider::new();
        let rule = RobotRule::untried();
        let found = candidates(&decider, 3, |d| rule.choose(d, key, &logits));
        assert_eq!(found.len(), 3);
        assert_eq!(found[0].move_x, Step::Plus);
        assert_eq!(found[1].move_x, Step::Zero);
        assert_ne!(found[1], found[2]);
        // The robot's own decider is untouched.
        assert_eq!(decider.taken_count(key), 0);
        let mut decider = decider;
        mark_taken(&mut decider, key, found[2]);
        assert!(decider.was_taken(key, found[2]));
        assert_eq!(decider.taken_count(key), 1);
    }
}
