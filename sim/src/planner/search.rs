//! The search itself: nodes over (base pose, leg set), successors queued on the cheap tests,
//! and the plan's reconstruction. When a queued successor's steps are proven, and why that
//! changes nothing the search does, is [`super::lazy`]'s subject.

use super::broad_phase::ObstacleBox;
use super::broad_phase::YawBoxes;
use super::broad_phase::AABB_SLACK_M;
use super::heuristic::DistanceField;
use super::heuristic::Heuristic;
use super::heuristic::LegHint;
use super::legs::LegLattice;
use super::legs::LegSet;
use super::moves::BaseMove;
use super::moves::Pose;
use super::moves::PoseKey;
use super::way::StateClearance;
use super::Plan;
use super::PlanOutcome;
use super::PlannerConfig;
use crate::env::Env;
use crate::state::RobotState;
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
    /// The leg configurations the robot can be in here after `steps` steps once `evaluated`;
    /// before, the candidates the cheap tests leave (a superset of them).
    pub(super) legs: LegSet,
    pub(super) steps: u32,
    /// The pose-only bound on the steps left ([`Heuristic::steps`]; 0 at a goal).
    pub(super) h: u32,
    pub(super) parent: u32,
    /// Index into the base moves of the move from the parent.
    pub(super) base_move: u8,
    /// Beaten by another node at its pose, or no leg configuration reachable: skipped when
    /// popped (see [`super::lazy`]).
    pub(super) dead: bool,
    /// The members of `legs` already proven valid (all of them once `evaluated`).
    pub(super) proven: LegSet,
    /// Whether `legs` is the valid set (the step from the parent proven per configuration).
    pub(super) evaluated: bool,
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
    /// End poses the broad phase called colliding, so checked as well.
    pub(super) cross_checked_ends: usize,
    /// Rounds of proofs run ([`Search::prove`]: a node's configurations, all or the ones that
    /// hold its priority down), for the tests of laziness.
    pub(super) evaluations: usize,
    /// The obstacles' boxes, as the simulator builds them, loosened by the slack.
    pub(super) obstacle_boxes: Vec<ObstacleBox>,
    pub(super) give_up_m: f32,
    pub(super) max_steps: u32,
    pub(super) nodes: Vec<Node>,
    /// Per pose, the nodes that reached it and are not dead, evaluated or not (for dominance).
    pub(super) seen: FastMap<PoseKey, Vec<u32>>,
    pub(super) open: BinaryHeap<Open>,
}

impl<'a> Search<'a> {
    pub(super) fn new(env: &'a Env, config: &'a PlannerConfig, max_steps: u32) -> Self {
        let start = *env.state();
        let lattice = LegLattice::new(env.robot());
        let heuristic = Heuristic {
            field: DistanceField::new(env, start.position),
            target: env.target(),
            success_radius_m: env.config().success_radius_m,
            lattice: *env.lattice(),
        };
        let leg_hint = (config.heuristic_weight > 1.0).then(|| LegHint::new(env, &lattice));
        Search {
            env,
            config,
            moves: BaseMove::all(&config.allowed),
            heuristic,
            leg_hint,
            boxes: (0..env.robot().yaw_steps_per_turn())
                .map(|_| None)
                .collect(),
            end_clear: FastMap::default(),
            in_arena: FastMap::default(),
            state_clearance: FastMap::default(),
            cross_check: false,
            cross_checked: 0,
            cross_checked_ends: 0,
            evaluations: 0,
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
            // The episode's own limit, which counts from where the episode started: a search from
            // a state mid-episode (the stack's look-ahead, the expert labeller) that counted from
            // the current state would allow, from a state farther out, a plan the episode ends.
            give_up_m: env.give_up_distance_m(),
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
            h: 0,
            parent: 0,
            base_move: 0,
            dead: false,
            proven: legs,
            evaluated: true,
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
            // A successor's steps are proven when it is popped (or earlier, when another node's
            // dominance needs its set). The weighted search's leg hint may then rise: the node
            // goes back at the priority its valid set gives, or the one its configurations not
            // yet refuted give, when refuting some of them was enough to lift it.
            if !self.nodes[node as usize].evaluated
                && (self.surely_beaten(node) || !self.prove(node, Some(f)))
            {
                continue;
            }
            let true_f = self.priority(node);
            if true_f != f {
                self.open.push(Open {
                    f: true_f,
                    steps: self.nodes[node as usize].steps,
                    node,
                });
                continue;
            }
            if !self.survives(node) {
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
        let from = RobotState::new(pose.position, pose.yaw_steps, self.env.lattice());
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
            // The valid set is a subset of the candidates: if a known set already holds them, the
            // node is beaten (see [`super::lazy`]) and its steps need no proof.
            if candidates.is_empty() || self.is_dominated(key, next_steps, &candidates) {
                continue;
            }
            let index = self.nodes.len() as u32;
            self.nodes.push(Node {
                pose: next_pose,
                legs: candidates,
                steps: next_steps,
                h,
                parent: node,
                base_move: m as u8,
                dead: false,
                proven: LegSet::default(),
                evaluated: false,
                goal,
            });
            self.seen.entry(key).or_default().push(index);
            if goal {
                // A goal may be accepted at once, so its steps are proven now.
                if !self.evaluate(index) || !self.survives(index) {
                    continue;
                }
                if self.config.heuristic_weight > 1.0 || next_steps as f32 <= f {
                    // Every plan still queued costs at least the popped f (the heuristic never
                    // overestimates), so a goal no deeper than f is shortest. A deeper goal
                    // waits in the queue at f = its steps until nothing better is left.
                    return Some(index);
                }
            }
            self.open.push(Open {
                f: self.priority(index),
                steps: next_steps,
                node: index,
            });
        }
        None
    }

    /// The queue priority of a node: its steps plus the weighted bound. The weighted search
    /// orders by the leg hint too, on the node's current set; the pruning keeps to the
    /// admissible `h`, so exhausting the space still proves the scene unsolvable. The hint is a
    /// minimum over the set, so a node's priority only rises when its candidates shrink to the
    /// valid set.
    pub(super) fn priority(&self, node: u32) -> f32 {
        let n = &self.nodes[node as usize];
        let order_h = match &self.leg_hint {
            Some(hint) if !n.goal => n.h.max(hint.steps(&n.pose, self.env.target(), &n.legs)),
            _ => n.h,
        };
        n.steps as f32 + self.config.heuristic_weight * order_h as f32
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

    /// Every step the planner's own proof of the way there accepts, the simulator accepts too,
    /// and every end pose the broad phase calls colliding, the simulator's test calls colliding:
    /// searches on generated scenes of every kind with obstacles, each such verdict put to the
    /// simulator as well (the search asserts it). The searches prove a small share of the steps
    /// they generate (lazy edge evaluation), which the test reports.
    #[test]
    fn the_planners_proof_accepts_only_steps_the_simulator_accepts() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let (mut checked, mut ends, mut proven, mut nodes) = (0, 0, 0, 0);
        for kind in SceneKind::ALL {
            for scene in generate_many(crate::generate::SceneRobot::shipped(), kind, &mut rng, 2) {
                let env = Env::new(&scene, EnvConfig::default()).unwrap();
                for weight in [1.0, FALLBACK_WEIGHT] {
                    let config = PlannerConfig {
                        max_expansions: 150,
                        heuristic_weight: weight,
                        ..PlannerConfig::default()
                    };
                    let mut search = Search::new(&env, &config, u32::MAX);
                    search.cross_check = true;
                    search.run();
                    checked += search.cross_checked;
                    ends += search.cross_checked_ends;
                    proven += search.evaluations;
                    nodes += search.nodes.len();
                }
            }
        }
        println!(
            "{checked} steps the planner's proof accepted, all accepted by the simulator; \
             {ends} end poses the broad phase called colliding, all colliding; \
             {proven} rounds of proofs for {nodes} nodes generated"
        );
        assert!(proven < nodes, "{proven} of {nodes}");
        assert!(ends > 10_000, "{ends}");
        assert!(checked > 10_000, "{checked}");
    }
}
