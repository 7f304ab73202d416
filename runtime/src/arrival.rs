//! The last step: when one action ends the mission, take it.
//!
//! The policy steers well from afar but is imprecise in the last decimetres: on the held-out
//! complex scenes most of its failures end within 0.3 m of the target, the robot dithering
//! around it until the step limit (docs/results.md, "The last step"). The target is in the
//! policy's own state vector, in the robot frame, and a step's translation is along the axes
//! the robot has when it decides ([`crate::motion::BaseDisplacement`]), so which actions end
//! within the mission's radius is plain arithmetic. [`Arrival`] gives the
//! [`crate::decision::Decider`] that test as a check level ahead of all others: at an
//! observation where nothing was taken yet, when some action arrives, the policy's most
//! probable such action is taken (one the collision guard passes, if a guard runs:
//! [`crate::guard::CollisionGuard::choose`]); otherwise nothing changes.
//!
//! Why one step and not a short search: a breadth-first search for the shortest ways over
//! straight moves that the guard passes, up to 7 steps, reached no more targets (the policy's
//! near misses are mostly beside a bar, which needs the body raised and the legs around it, not
//! a straight way) and added collisions where the guard's map misses an obstacle's edge
//! (docs/results.md, "The last step").

use crate::action::{Action, ActionLattice, Step, CHOICES, DIMS};
use crate::decision::{Checked, Decider, ObservationKey};
use crate::motion::BaseDisplacement;
use nalgebra::Vector2;

/// The simulator's success radius: the body centre within 5 cm of the target.
pub const DEFAULT_RADIUS_M: f32 = 0.05;

/// Where the target is, seen from the robot, and how near counts as arrived.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Arrival {
    target_m: Vector2<f32>,
    radius_m: f32,
    lattice: ActionLattice,
}

impl Arrival {
    /// The target at `target_m` in the robot frame (x ahead, y left), reached once the body
    /// centre is within `radius_m` of it by a step of `lattice`. A non-finite target or radius
    /// arrives nowhere.
    pub fn new(target_m: Vector2<f32>, radius_m: f32, lattice: &ActionLattice) -> Arrival {
        let finite = target_m.x.is_finite() && target_m.y.is_finite() && radius_m.is_finite();
        Arrival {
            target_m: if finite { target_m } else { Vector2::zeros() },
            radius_m: if finite { radius_m } else { -1.0 },
            lattice: *lattice,
        }
    }

    /// The target as the policy's state vector holds it (millimetres, robot frame: entries 2
    /// and 3, [`crate::observation::STATE_LEN`]).
    pub fn from_state_mm(state_mm: &[i32], radius_m: f32, lattice: &ActionLattice) -> Arrival {
        let mm = |i: usize| state_mm.get(i).map_or(f32::NAN, |&v| v as f32 * 1.0e-3);
        Arrival::new(Vector2::new(mm(2), mm(3)), radius_m, lattice)
    }

    /// The target as a state vector in metres holds it (entries 2 and 3).
    pub fn from_state_m(state_m: &[f32], radius_m: f32, lattice: &ActionLattice) -> Arrival {
        let m = |i: usize| state_m.get(i).copied().unwrap_or(f32::NAN);
        Arrival::new(Vector2::new(m(2), m(3)), radius_m, lattice)
    }

    /// Whether taking `action` ends with the body centre within the radius of the target.
    pub fn reached_by(&self, action: Action) -> bool {
        let step = BaseDisplacement::of_action(action, &self.lattice);
        crate::trig::hypot(self.target_m.x - step.dx_m, self.target_m.y - step.dy_m)
            <= self.radius_m
    }

    /// Whether some action reaches the target in one step (only the two move heads matter).
    pub fn within_one_step(&self) -> bool {
        Step::ALL.iter().any(|&move_x| {
            Step::ALL.iter().any(|&move_y| {
                self.reached_by(Action {
                    move_x,
                    move_y,
                    ..Action::IDLE
                })
            })
        })
    }

    /// Whether the arrival level applies at observation `key`: some action reaches the target
    /// and nothing has been taken here yet. A second decision at the same observation means
    /// the arriving step was refused by the world (it would have ended the mission
    /// otherwise); the other arriving actions, the same move with another turn or leg change,
    /// most likely meet the same obstacle, so from then on the policy decides alone.
    pub fn applies<const STATES: usize>(
        &self,
        decider: &Decider<STATES>,
        key: ObservationKey,
    ) -> bool {
        decider.taken_count(key) == 0 && self.within_one_step()
    }

    /// The decider's choice with arrival first, without a guard: where [`Self::applies`], the
    /// most probable action that reaches the target; else [`Decider::choose`]. [`Checked::level`] is
    /// `Some(0)` for an arriving action and `None` for the plain choice.
    pub fn choose<const STATES: usize, L: Copy + Into<f32>>(
        &self,
        decider: &mut Decider<STATES>,
        key: ObservationKey,
        logits: &[L; DIMS * CHOICES],
    ) -> Checked {
        let levels = usize::from(self.applies(decider, key));
        decider.choose_checked(key, logits, levels, |_, action| self.reached_by(action))
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::indexing_slicing)]
mod tests {
    use super::*;
    use crate::decision::tests::forward_logits;

    #[test]
    fn a_target_behind_and_left_is_reached_by_moving_back_and_left() {
        let arrival = Arrival::new(
            Vector2::new(-0.049, 0.034),
            DEFAULT_RADIUS_M,
            &ActionLattice::PAPER,
        );
        assert!(arrival.within_one_step());
        let mut decider: Decider = Decider::new();
        let checked = arrival.choose(&mut decider, ObservationKey(1), &forward_logits());
        assert_eq!(checked.level, Some(0));
        assert!(arrival.reached_by(checked.action));
        // Of the arriving moves, the policy's idle heads are kept: no turn, no leg change.
        assert_eq!(checked.action.yaw, Step::Zero);
        assert_eq!(checked.action.clearance, Step::Zero);
        assert_eq!(checked.action.track, Step::Zero);
    }

    #[test]
    fn far_from_the_target_the_policy_decides_alone() {
        let arrival = Arrival::new(
            Vector2::new(-0.5, 0.3),
            DEFAULT_RADIUS_M,
            &ActionLattice::PAPER,
        );
        assert!(!arrival.within_one_step());
        let mut decider: Decider = Decider::new();
        let checked = arrival.choose(&mut decider, ObservationKey(1), &forward_logits());
        assert_eq!(checked.level, None);
        assert_eq!(checked.action.move_x, Step::Plus);
    }

    #[test]
    fn a_refused_arrival_is_not_retried_with_another_turn() {
        let arrival = Arrival::new(
            Vector2::new(0.06, 0.0),
            DEFAULT_RADIUS_M,
            &ActionLattice::PAPER,
        );
        let mut decider: Decider = Decider::new();
        let key = ObservationKey(1);
        let first = arrival.choose(&mut decider, key, &forward_logits());
        assert_eq!(first.level, Some(0));
        // Still at the same observation: the world refused it. Now the policy decides alone.
        assert!(!arrival.applies(&decider, key));
        let second = arrival.choose(&mut decider, key, &forward_logits());
        assert_eq!(second.level, None);
        assert_ne!(second.action, first.action);
    }

    #[test]
    fn reached_matches_the_step_geometry() {
        // 0.12 m ahead: a forward step leaves 0.07 m, outside 5 cm; at 0.09 m it leaves 0.04 m.
        let far = Arrival::new(
            Vector2::new(0.12, 0.0),
            DEFAULT_RADIUS_M,
            &ActionLattice::PAPER,
        );
        let near = Arrival::new(
            Vector2::new(0.09, 0.0),
            DEFAULT_RADIUS_M,
            &ActionLattice::PAPER,
        );
        let forward = Action {
            move_x: Step::Plus,
            ..Action::IDLE
        };
        assert!(!far.reached_by(forward));
        assert!(near.reached_by(forward));
        assert!(!near.reached_by(Action::IDLE));
    }

    #[test]
    fn bad_data_arrives_nowhere() {
        assert!(!Arrival::new(
            Vector2::new(f32::NAN, 0.0),
            DEFAULT_RADIUS_M,
            &ActionLattice::PAPER
        )
        .within_one_step());
        assert!(
            !Arrival::new(Vector2::new(0.0, 0.0), f32::INFINITY, &ActionLattice::PAPER)
                .within_one_step()
        );
        assert!(
            !Arrival::from_state_mm(&[0, 0], DEFAULT_RADIUS_M, &ActionLattice::PAPER)
                .within_one_step()
        );
        assert!(
            Arrival::from_state_mm(&[0, 0, 30, 0], DEFAULT_RADIUS_M, &ActionLattice::PAPER)
                .within_one_step()
        );
    }
}
