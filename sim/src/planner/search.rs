//! The search itself: nodes over (base pose, leg set), dominance, successors and the plan's
//! reconstruction.

use super::broad_phase::classify;
use super::broad_phase::shifted;
use super::broad_phase::sweep_meets;
use super::broad_phase::Contact;
use super::broad_phase::ObstacleBox;
use super::broad_phase::YawBoxes;
use super::broad_phase::AABB_SLACK_M;
use super::broad_phase::SWEEP_GROW_M;
use super::heuristic::DistanceField;
use super::heuristic::Heuristic;
use super::heuristic::LegHint;
use super::legs::LegLattice;
use super::legs::LegSet;
use super::legs::LEG_COLS;
use super::moves::BaseMove;
use super::moves::Pose;
use super::moves::PoseKey;
use super::way::way_proven;
use super::way::StateClearance;
use super::Plan;
use super::PlanOutcome;
use super::PlannerConfig;
use crate::collision::RobotParts;
use crate::env::Env;
use crate::env::InvalidAction;
use crate::state::{RobotState, YAW_STEPS_PER_TURN};
use nalgebra::Point3;
use parry3d::bounding_volume::{Aabb, BoundingVolume};
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::collections::HashMap;
use std::hash::BuildHasherDefault;
use std::hash::Hasher;
use wheelleg_runtime::action::Action;

/// FxHash-style hasher for the small integer keys of the search: the default SipHash costs more
/// than the rest of a fast-path successor.
#[derive(Default)]
pub(super) struct FastHasher(pub(super) u64);

impl Hasher for FastHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }

    fn write_i32(&mut self, i: i32) {
        self.write_u64(i as u32 as u64);
    }

    fn write_u16(&mut self, i: u16) {
        self.write_u64(i as u64);
    }

    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

pub(super) type FastMap<K, V> = HashMap<K, V, BuildHasherDefault<FastHasher>>;

pub(super) struct Node {
    pub(super) pose: Pose,
    pub(super) legs: LegSet,
    pub(super) steps: u32,
    pub(super) parent: u32,
    /// Index into the base moves of the move from the parent.
    pub(super) base_move: u8,
    /// Dominated by a node found later: skipped when popped.
    pub(super) dead: bool,
    /// Within the success radius (queued only to be accepted when it is the best in the queue).
    pub(super) goal: bool,
}

#[derive(PartialEq)]
pub(super) struct Open {
    pub(super) f: f32,
    pub(super) steps: u32,
    pub(super) node: u32,
}

impl Eq for Open {}

impl Ord for Open {
    fn cmp(&self, other: &Self) -> Ordering {
        // Smallest f first; among equals, deepest first, then newest first: with a tight
        // heuristic this dives straight along one shortest plan instead of widening over the
        // many equally short ones.
        other
            .f
            .total_cmp(&self.f)
            .then(self.steps.cmp(&other.steps))
            .then(self.node.cmp(&other.node))
    }
}

impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

pub(super) struct Search<'a> {
    pub(super) env: &'a Env,
    pub(super) config: &'a PlannerConfig,
    pub(super) lattice: LegLattice,
    pub(super) moves: Vec<BaseMove>,
    pub(super) heuristic: Heuristic,
    /// Leg-aware ordering hint, for the weighted search only (`None` when exact).
    pub(super) leg_hint: Option<LegHint>,
    /// Bounding boxes per yaw step, computed when the yaw is first met.
    pub(super) boxes: Vec<Option<YawBoxes>>,
    /// Whether the robot at a pose with a leg configuration (row * LEG_COLS + col) is clear of
    /// every obstacle; the same end pose is reached from many parents.
    pub(super) end_clear: FastMap<(PoseKey, u16), bool>,
    pub(super) in_arena: FastMap<PoseKey, bool>,
    /// Lower bounds on the clearance of lattice states, for [`way_proven`]; see
    /// [`state_clearance_m`].
    pub(super) state_clearance: StateClearance,
    /// Whether every step [`way_proven`] accepts is also put to `Env::check_transition`, which
    /// must accept it (tests of this module).
    pub(super) cross_check: bool,
    /// Steps so checked.
    pub(super) cross_checked: usize,
    /// The obstacles' boxes, as the simulator builds them, loosened by the slack.
    pub(super) obstacle_boxes: Vec<ObstacleBox>,
    pub(super) give_up_m: f32,
    pub(super) max_steps: u32,
    pub(super) nodes: Vec<Node>,
    /// Per pose, the live nodes that reached it (for dominance).
    pub(super) seen: FastMap<PoseKey, Vec<u32>>,
    pub(super) open: BinaryHeap<Open>,
}

impl<'a> Search<'a> {
    pub(super) fn new(env: &'a Env, config: &'a PlannerConfig, max_steps: u32) -> Self {
        let start = *env.state();
        let lattice = LegLattice::new(env.geometry());
        let heuristic = Heuristic {
            field: DistanceField::new(env, start.position),
            target: env.target(),
            success_radius_m: env.config().success_radius_m,
        };
        let leg_hint = (config.heuristic_weight > 1.0).then(|| LegHint::new(env, &lattice));
        Search {
            env,
            config,
            moves: BaseMove::all(&config.allowed),
            heuristic,
            leg_hint,
            boxes: (0..YAW_STEPS_PER_TURN).map(|_| None).collect(),
            end_clear: FastMap::default(),
            in_arena: FastMap::default(),
            state_clearance: FastMap::default(),
            cross_check: false,
            cross_checked: 0,
            obstacle_boxes: env
                .obstacles()
                .boxes()
                .iter()
                .map(|b| ObstacleBox {
                    aabb: Aabb::new(
                        Point3::new(b.min_x_m, b.min_y_m, 0.0),
                        Point3::new(b.max_x_m, b.max_y_m, b.height_m),
                    )
                    .loosened(AABB_SLACK_M),
                    centre: b.centre(),
                    half: b.half_extents(),
                })
                .collect(),
            // The episode gives up beyond its start distance plus the margin; the planner starts
            // from the current state, which is the start for every caller that plans a scene.
            give_up_m: (env.target() - start.position).norm() + env.config().give_up_margin_m,
            max_steps: env
                .config()
                .max_steps
                .saturating_sub(env.steps())
                .min(max_steps),
            lattice,
            nodes: Vec::new(),
            seen: FastMap::default(),
            open: BinaryHeap::new(),
        }
    }

    pub(super) fn run(&mut self) -> Plan {
        let start = *self.env.state();
        let Some((row, col)) = self.lattice.cell(&start) else {
            // The simulator never lets the robot stand in an unreachable leg pose.
            return Plan {
                outcome: PlanOutcome::Unsolvable,
                expansions: 0,
            };
        };
        let mut legs = LegSet::default();
        legs.insert(row, col);
        let pose = Pose {
            position: start.position,
            yaw_steps: start.yaw_steps,
        };
        self.nodes.push(Node {
            pose,
            legs,
            steps: 0,
            parent: 0,
            base_move: 0,
            dead: false,
            goal: false,
        });
        self.seen.insert(pose.key(), vec![0]);
        self.open.push(Open {
            f: 0.0,
            steps: 0,
            node: 0,
        });
        let mut expansions = 0;
        let shortest = self.config.heuristic_weight <= 1.0;
        while let Some(Open { f, node, .. }) = self.open.pop() {
            if self.nodes[node as usize].dead {
                continue;
            }
            if self.nodes[node as usize].goal {
                return self.solved(node, shortest, expansions);
            }
            if expansions >= self.config.max_expansions {
                return Plan {
                    outcome: PlanOutcome::BudgetExceeded,
                    expansions,
                };
            }
            expansions += 1;
            if self.nodes[node as usize].steps >= self.max_steps {
                continue;
            }
            if let Some(goal) = self.expand(node, f) {
                return self.solved(goal, shortest, expansions);
            }
        }
        Plan {
            outcome: PlanOutcome::Unsolvable,
            expansions,
        }
    }

    pub(super) fn solved(&self, goal: u32, shortest: bool, expansions: usize) -> Plan {
        Plan {
            outcome: PlanOutcome::Solved {
                actions: self.actions_to(goal),
                shortest,
            },
            expansions,
        }
    }

    /// Queues the successors of `node` (popped with priority `f`); returns a goal node that can
    /// be accepted at once.
    pub(super) fn expand(&mut self, node: u32, f: f32) -> Option<u32> {
        let (pose, legs, steps) = {
            let n = &self.nodes[node as usize];
            (n.pose, n.legs, n.steps)
        };
        let from = RobotState::new(pose.position, pose.yaw_steps);
        for m in 0..self.moves.len() {
            let next = from.after(self.moves[m].action);
            let next_pose = Pose {
                position: next.position,
                yaw_steps: next.yaw_steps,
            };
            let key = next_pose.key();
            let distance_m = (self.env.target() - next_pose.position).norm();
            if distance_m > self.give_up_m || !self.inside_arena(&next_pose, key) {
                continue;
            }
            let mut candidates = LegSet::default();
            for &(dc, dt) in &self.moves[m].leg_steps {
                candidates.union_with(&legs.shifted(dc, dt));
            }
            let candidates = candidates.intersection(&self.lattice.reachable);
            let next_steps = steps + 1;
            let goal = distance_m <= self.env.config().success_radius_m;
            let h = if goal {
                0
            } else {
                self.heuristic.steps(&next_pose)
            };
            if next_steps.saturating_add(h) > self.max_steps {
                // Even the most optimistic continuation runs past the step limit; dropping it
                // loses nothing and lets small step limits prove scenes unsolvable quickly.
                continue;
            }
            // The valid set is a subset of the candidates: if they are dominated, so is it, and
            // the collision checks can be skipped.
            if candidates.is_empty() || self.is_dominated(key, next_steps, &candidates) {
                continue;
            }
            let next_legs = self.valid_subset(&pose, &legs, m, &next_pose, key, &candidates);
            if next_legs.is_empty() || self.is_dominated(key, next_steps, &next_legs) {
                continue;
            }
            self.retire_dominated(key, next_steps, &next_legs);
            let index = self.nodes.len() as u32;
            self.nodes.push(Node {
                pose: next_pose,
                legs: next_legs,
                steps: next_steps,
                parent: node,
                base_move: m as u8,
                dead: false,
                goal,
            });
            self.seen.entry(key).or_default().push(index);
            if goal && (self.config.heuristic_weight > 1.0 || next_steps as f32 <= f) {
                // Every plan still queued costs at least the popped f (the heuristic never
                // overestimates), so a goal no deeper than f is shortest. A deeper goal waits in
                // the queue at f = its steps until nothing better is left.
                return Some(index);
            }
            // The weighted search orders by the leg hint too; the pruning above keeps to the
            // admissible `h`, so exhausting the space still proves the scene unsolvable.
            let order_h = match &self.leg_hint {
                Some(hint) if !goal => h.max(hint.steps(&next_pose, self.env.target(), &next_legs)),
                _ => h,
            };
            let f = next_steps as f32 + self.config.heuristic_weight * order_h as f32;
            self.open.push(Open {
                f,
                steps: next_steps,
                node: index,
            });
        }
        None
    }

    /// Whether `pose` is inside the arena. The simulator checks the arena before anything else,
    /// so a transition to an unreachable leg pose answers exactly that question, cheaply.
    pub(super) fn inside_arena(&mut self, pose: &Pose, key: PoseKey) -> bool {
        let env = self.env;
        *self.in_arena.entry(key).or_insert_with(|| {
            let here = RobotState::new(pose.position, pose.yaw_steps);
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
                Contact::Collides => false,
                Contact::Unknown => {
                    *self.end_clear.entry((key, cell as u16)).or_insert_with(|| {
                        RobotParts::new(
                            geometry,
                            to.position,
                            to.yaw_rad(),
                            to.leg_config(geometry),
                        )
                        .is_ok_and(|parts| !env.obstacles().collides(&parts))
                    })
                }
            };
            if !end_clear {
                continue;
            }
            // The planner's own tests first, for every predecessor; the simulator only for a
            // candidate none of them settles. Only whether some predecessor's step is valid
            // matters, not which.
            let mut unsettled: heapless::Vec<RobotState, 9> = heapless::Vec::new();
            let mut ok = false;
            for &(dc, dt) in &self.moves[m].leg_steps {
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

    /// Whether a node already known at the pose has no more steps and a superset of the leg
    /// configurations: whatever a new node could do, that one does as well or sooner.
    pub(super) fn is_dominated(&self, key: PoseKey, steps: u32, legs: &LegSet) -> bool {
        self.seen.get(&key).is_some_and(|known| {
            known.iter().any(|&k| {
                let n = &self.nodes[k as usize];
                n.steps <= steps && legs.is_subset_of(&n.legs)
            })
        })
    }

    /// Retires the known nodes at the pose that a new node with `steps` and `legs` dominates.
    pub(super) fn retire_dominated(&mut self, key: PoseKey, steps: u32, legs: &LegSet) {
        let Some(known) = self.seen.get_mut(&key) else {
            return;
        };
        let nodes = &mut self.nodes;
        known.retain(|&k| {
            let n = &mut nodes[k as usize];
            let worse = steps <= n.steps && n.legs.is_subset_of(legs);
            n.dead |= worse;
            !worse
        });
    }

    /// The actions from the start to `goal`: walking back from any leg configuration of the
    /// goal, each step picks a configuration of the parent's set from which the simulator
    /// accepts the transition (one exists: that is how the configuration got into the set).
    pub(super) fn actions_to(&self, goal: u32) -> Vec<Action> {
        let mut node = goal;
        let (mut row, mut col) = self.nodes[node as usize]
            .legs
            .iter()
            .next()
            .expect("nodes are never empty");
        let mut actions = Vec::with_capacity(self.nodes[node as usize].steps as usize);
        while node != 0 {
            let n = &self.nodes[node as usize];
            let parent = &self.nodes[n.parent as usize];
            let base = &self.moves[n.base_move as usize];
            let to = self.lattice.state(&n.pose, row, col);
            let (dc, dt) = base
                .leg_steps
                .iter()
                .copied()
                .find(|&(dc, dt)| {
                    let (r, c) = (row as i32 - dc, col as i32 - dt);
                    r >= 0
                        && c >= 0
                        && parent.legs.contains(r as usize, c as usize)
                        && self
                            .env
                            .check_transition(
                                &self.lattice.state(&parent.pose, r as usize, c as usize),
                                &to,
                            )
                            .is_ok()
                })
                .unwrap_or_else(|| {
                    panic!("planner bug: no valid predecessor for step {}", n.steps)
                });
            actions.push(base.with_legs(dc, dt));
            row = (row as i32 - dc) as usize;
            col = (col as i32 - dt) as usize;
            node = n.parent;
        }
        actions.reverse();
        actions
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::EnvConfig;
    use crate::generate::{generate_many, SceneKind};
    use crate::planner::FALLBACK_WEIGHT;
    use rand::SeedableRng;

    /// Every step the planner's own proof of the way there accepts, the simulator accepts too:
    /// searches on generated scenes of every kind with obstacles, each such step put to
    /// `Env::check_transition` as well (the search asserts it).
    #[test]
    fn the_planners_proof_accepts_only_steps_the_simulator_accepts() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let mut checked = 0;
        for kind in SceneKind::ALL {
            for scene in generate_many(kind, &mut rng, 2) {
                let env = Env::new(&scene, EnvConfig::default()).unwrap();
                for weight in [1.0, FALLBACK_WEIGHT] {
                    let config = PlannerConfig {
                        max_expansions: 40,
                        heuristic_weight: weight,
                        ..PlannerConfig::default()
                    };
                    let mut search = Search::new(&env, &config, u32::MAX);
                    search.cross_check = true;
                    search.run();
                    checked += search.cross_checked;
                }
            }
        }
        println!("{checked} steps the planner's proof accepted, all accepted by the simulator");
        assert!(checked > 10_000, "{checked}");
    }
}
