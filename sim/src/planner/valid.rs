//! Which leg configurations a step reaches: the planner's cheap tests, its own proof of the
//! way there, and the simulator for what they leave (see [`Search::valid_subset`]).

use super::broad_phase::classify;
use super::broad_phase::shifted;
use super::broad_phase::sweep_meets;
use super::broad_phase::Contact;
use super::broad_phase::ObstacleBox;
use super::broad_phase::YawBoxes;
use super::broad_phase::SWEEP_GROW_M;
use super::legs::LegSet;
use super::legs::LEG_COLS;
use super::moves::Pose;
use super::moves::PoseKey;
use super::search::Search;
use super::way::way_proven;
use crate::collision::RobotParts;
use crate::env::Env;
use crate::env::InvalidAction;
use crate::state::RobotState;

use parry3d::bounding_volume::BoundingVolume;

impl Search<'_> {
    /// Whether `pose` is inside the arena. The simulator checks the arena before anything else,
    /// so a transition to an unreachable leg pose answers exactly that question, cheaply.
    pub(super) fn inside_arena(&mut self, pose: &Pose, key: PoseKey) -> bool {
        let env = self.env;
        *self.in_arena.entry(key).or_insert_with(|| {
            let here = RobotState::new(pose.position, pose.yaw_steps, env.lattice());
            let probe = RobotState {
                track_steps: i32::MAX / 4,
                ..here
            };
            env.check_transition(&here, &probe) != Err(InvalidAction::OutOfBounds)
        })
    }

    /// The members of `candidates` the robot can take at `next` by move `m` from some member
    /// of `legs` at `pose`.
    ///
    /// Mirrors the simulator's `check_transition` with cheap sufficient tests first, and asks
    /// the simulator itself whenever they do not settle a case, so it never accepts a
    /// transition the simulator would refuse (the replay of every plan checks this):
    /// - the end pose: the simulator's exact test only looks at part/obstacle pairs whose
    ///   boxes meet, so an end pose whose boxes meet no obstacle's box is clear (first tested
    ///   for the box over all leg configurations at this yaw, then per candidate), and one
    ///   that the separating-axis tests of [`classify`] settle needs no exact test;
    /// - the way there: the simulator accepts it without a proof when no part's span of start
    ///   and end boxes, grown by half the step's motion bound, meets an obstacle box
    ///   ([`sweep_meets`]); otherwise the simulator decides.
    pub(super) fn valid_subset(
        &mut self,
        pose: &Pose,
        legs: &LegSet,
        m: usize,
        next: &Pose,
        key: PoseKey,
        candidates: &LegSet,
    ) -> LegSet {
        let env = self.env;
        let geometry = env.geometry();
        let yaw = next.yaw_steps as usize;
        if self.boxes[yaw].is_none() {
            self.boxes[yaw] = Some(YawBoxes::new(geometry, &self.lattice, next.yaw_steps));
        }
        let all = shifted(
            &self.boxes[yaw].as_ref().expect("just filled").all,
            next.position,
        );
        let near: Vec<ObstacleBox> = self
            .obstacle_boxes
            .iter()
            .filter(|o| o.aabb.intersects(&all))
            .copied()
            .collect();
        let from_yaw = pose.yaw_steps as usize;
        if self.boxes[from_yaw].is_none() {
            self.boxes[from_yaw] = Some(YawBoxes::new(geometry, &self.lattice, pose.yaw_steps));
        }
        // Obstacles the way there could meet: near either end's boxes over every leg pose,
        // grown by the most any point moves in half a step.
        let span = shifted(
            &self.boxes[from_yaw].as_ref().expect("just filled").all,
            pose.position,
        )
        .merged(&all)
        .loosened(SWEEP_GROW_M);
        let near_way: Vec<ObstacleBox> = self
            .obstacle_boxes
            .iter()
            .filter(|o| o.aabb.intersects(&span))
            .copied()
            .collect();
        if near.is_empty() && near_way.is_empty() {
            return *candidates;
        }
        let mut valid = LegSet::default();
        for (row, col) in candidates.iter() {
            let cell = row * LEG_COLS + col;
            let end_boxes = self.boxes[yaw].as_ref().expect("just filled").get(row, col);
            let end_whole = shifted(&end_boxes.whole, next.position);
            let end_near = near.iter().any(|o| o.aabb.intersects(&end_whole));
            if !end_near && near_way.is_empty() {
                valid.insert(row, col);
                continue;
            }
            let to = self.lattice.state(next, row, col);
            let end_clear = match classify(end_boxes, next.position, &near) {
                _ if !end_near => true,
                Contact::Clear => true,
                Contact::Collides => {
                    if self.cross_check {
                        self.cross_checked_ends += 1;
                        assert!(
                            !exact_end_clear(env, &to),
                            "the broad phase called {to:?} colliding"
                        );
                    }
                    false
                }
                Contact::Unknown => *self
                    .end_clear
                    .entry((key, cell as u16))
                    .or_insert_with(|| exact_end_clear(env, &to)),
            };
            if !end_clear {
                continue;
            }
            // The planner's own tests first, for every predecessor; the simulator only for a
            // candidate none of them settles. Only whether some predecessor's step is valid
            // matters, not which.
            let mut unsettled: heapless::Vec<RobotState, 9> = heapless::Vec::new();
            let mut ok = false;
            for &(dc, dt) in &self.moves[m].proof_order {
                let (r, c) = (row as i32 - dc, col as i32 - dt);
                if r < 0 || c < 0 || !legs.contains(r as usize, c as usize) {
                    continue;
                }
                let from = self.lattice.state(pose, r as usize, c as usize);
                // A leg pose the legs cannot take on the way is refused by the simulator.
                let Ok(bound_m) = env.motion_bound_m(&from, &to) else {
                    continue;
                };
                // Every point of a part stays within half the motion bound of where it is at
                // one end: when no part's span of start and end, grown by that, meets an
                // obstacle box, the simulator's own first sweep test accepts the step.
                let start_boxes = self.boxes[from_yaw]
                    .as_ref()
                    .expect("filled above")
                    .get(r as usize, c as usize);
                let sweep_clear = 0.5 * bound_m <= SWEEP_GROW_M
                    && !sweep_meets(
                        start_boxes,
                        pose.position,
                        end_boxes,
                        next.position,
                        0.5 * bound_m,
                        &near_way,
                    );
                if sweep_clear {
                    ok = true;
                    break;
                }
                if way_proven(
                    env,
                    &mut self.state_clearance,
                    (&from, pose.key(), r as usize * LEG_COLS + c as usize),
                    (&to, key, cell),
                    bound_m,
                ) {
                    if self.cross_check {
                        self.cross_checked += 1;
                        assert_eq!(
                            env.check_transition(&from, &to),
                            Ok(()),
                            "the planner's proof accepted {from:?} -> {to:?}"
                        );
                    }
                    ok = true;
                    break;
                }
                unsettled.push(from).expect("at most 9 leg steps");
            }
            if ok
                || unsettled
                    .iter()
                    .any(|from| env.check_transition(from, &to).is_ok())
            {
                valid.insert(row, col);
            }
        }
        valid
    }
}

/// The simulator's end-pose test: whether the robot at `to` is clear of every obstacle.
fn exact_end_clear(env: &Env, to: &RobotState) -> bool {
    let geometry = env.geometry();
    RobotParts::new(geometry, to.position, to.yaw_rad(), to.leg_config(geometry))
        .is_ok_and(|parts| !env.obstacles().collides(&parts))
}
