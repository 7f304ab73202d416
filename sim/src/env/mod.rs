//! One episode of the navigation task: reset to a scenario, step with actions, observe.
//!
//! An invalid action (collision, impossible leg pose, leaving the arena) is undone: the state
//! stays as before the action, the step counts, and the reward carries the invalid penalty.
//! Collision is checked at the end pose and, when the robot is near an obstacle, along the
//! whole way there (proven clear from distances, not sampled), so that no part passes through
//! an obstacle within a step.

use crate::collision::{ObstacleSet, RobotParts};
use crate::height_map::{self, HeightMap};
use crate::reward::RewardTerms;
use crate::robot::SimulatedRobot;
use crate::scenario::{Scenario, ScenarioError};
use crate::state::RobotState;
use nalgebra::{Point2, Vector2};
use wheelleg_runtime::action::Action;
use wheelleg_runtime::action::ActionLattice;
use wheelleg_runtime::leg::IkError;
use wheelleg_runtime::observation::STATE_LEN;
use wheelleg_runtime::robot::RobotGeometry;

mod guard_map;
mod way_proof;
mod way_there;

pub use guard_map::GuardMap;
pub(crate) use way_proof::{proof_cap_m, prove_way, ProofPose, WayClearance};
pub(crate) use way_there::{horizontal_reach_at_track_m, horizontal_reach_m};

/// Motion shorter than this that cannot be proven clear of an obstacle counts as touching it
/// (see [`Env::check_transition`]): 0.1 mm, far below what a real robot tracks, far above
/// parry's rounding.
pub const GRAZE_TOLERANCE_M: f32 = 1.0e-4;

/// Episode rules. Defaults are documented in docs/simulator.md.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvConfig {
    /// Episode ends (failed) after this many steps.
    pub max_steps: u32,
    /// Success when the body centre is this close to the target.
    pub success_radius_m: f32,
    /// Episode ends (failed) when the robot is farther from the target than its start distance
    /// plus this margin.
    pub give_up_margin_m: f32,
    /// The arena is the box around start and target grown by this margin; leaving it is an
    /// invalid action.
    pub arena_margin_m: f32,
    /// Reward term of an undone action (collision, impossible pose, out of bounds); the paper's
    /// is [`crate::reward::INVALID_PENALTY`], -0.1.
    pub invalid_reward: f32,
    /// The robot simulated (a description's geometry and lattice, [`SimulatedRobot::of`]); the
    /// shipped robot by default.
    pub robot: SimulatedRobot,
}

impl Default for EnvConfig {
    fn default() -> Self {
        EnvConfig {
            max_steps: 100,
            success_radius_m: wheelleg_runtime::arrival::DEFAULT_RADIUS_M,
            give_up_margin_m: 0.5,
            arena_margin_m: 0.6,
            invalid_reward: crate::reward::INVALID_PENALTY,
            robot: SimulatedRobot::SHIPPED,
        }
    }
}

/// Why an action was undone.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InvalidAction {
    /// A part of the robot would hit an obstacle.
    Collision,
    /// The legs cannot take the requested (clearance, track).
    Impossible(IkError),
    /// The robot would leave the arena.
    OutOfBounds,
}

/// A motion that touches an obstacle somewhere along its path ([`Env::check_swept`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SweptCollision {
    /// Where along the motion (0 = start, 1 = end) the first colliding pose sampled lies.
    pub fraction: f32,
}

/// Where the episode stands after a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    /// Still going.
    Running,
    /// Reached the target.
    Success,
    /// Drove too far from the target.
    TooFar,
    /// Ran out of steps.
    StepLimit,
}

impl Status {
    /// Whether the episode is over.
    pub fn is_done(self) -> bool {
        self != Status::Running
    }
}

/// What one step did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOutcome {
    /// The reward's terms; `reward.total()` is the reward.
    pub reward: RewardTerms,
    /// Why the action was undone, if it was.
    pub invalid: Option<InvalidAction>,
    /// The episode's status after the step.
    pub status: Status,
}

/// The policy's input: height map plus robot state.
#[derive(Clone, Debug, PartialEq)]
pub struct Observation {
    /// Robot-centred height map.
    pub height_map: HeightMap,
    /// Clearance, track, target x and y in the robot frame.
    pub state: [f32; STATE_LEN],
}

impl Default for Observation {
    fn default() -> Self {
        Observation {
            height_map: [0.0; wheelleg_runtime::observation::HEIGHT_MAP_CELLS],
            state: [0.0; STATE_LEN],
        }
    }
}

/// A running episode.
#[derive(Clone, Debug)]
pub struct Env {
    config: EnvConfig,
    obstacles: ObstacleSet,
    target: Point2<f32>,
    arena_min: Point2<f32>,
    arena_max: Point2<f32>,
    state: RobotState,
    steps: u32,
    start_distance_m: f32,
    status: Status,
    collisions: u32,
    /// No part of the robot is ever farther than this from its centre, horizontally.
    reach_m: f32,
    /// The robot's parts at `state`, when a step's check placed them there: the start of the
    /// next step's check ([`Env::pose_between`] at 0 gives the same values).
    parts_here: Option<RobotParts>,
}

/// Stepping an episode that is over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EpisodeOver;

impl Env {
    /// Starts an episode of `scenario` with the robot of `config`.
    pub fn new(scenario: &Scenario, config: EnvConfig) -> Result<Self, ScenarioError> {
        scenario.validate(&config.robot)?;
        let start = scenario.start.position;
        let margin = Vector2::repeat(config.arena_margin_m);
        let arena_min = Point2::new(
            start.x.min(scenario.target.x),
            start.y.min(scenario.target.y),
        ) - margin;
        let arena_max = Point2::new(
            start.x.max(scenario.target.x),
            start.y.max(scenario.target.y),
        ) + margin;
        let start_distance_m = (scenario.target - start).norm();
        Ok(Env {
            config,
            obstacles: ObstacleSet::new(&scenario.obstacles),
            target: scenario.target,
            arena_min,
            arena_max,
            state: scenario.start,
            steps: 0,
            start_distance_m,
            status: if start_distance_m <= config.success_radius_m {
                Status::Success
            } else {
                Status::Running
            },
            collisions: 0,
            reach_m: horizontal_reach_m(config.robot.geometry()),
            parts_here: None,
        })
    }

    /// The robot's current state.
    pub fn state(&self) -> &RobotState {
        &self.state
    }

    /// The target.
    pub fn target(&self) -> Point2<f32> {
        self.target
    }

    /// The distance from the target beyond which the episode gives up ([`Status::TooFar`]):
    /// the start's distance plus the margin, wherever the robot is now.
    pub fn give_up_distance_m(&self) -> f32 {
        self.start_distance_m + self.config.give_up_margin_m
    }

    /// Steps taken so far.
    pub fn steps(&self) -> u32 {
        self.steps
    }

    /// Collisions so far (undone actions that would have hit an obstacle).
    pub fn collisions(&self) -> u32 {
        self.collisions
    }

    /// The episode's status.
    pub fn status(&self) -> Status {
        self.status
    }

    /// The rules.
    pub fn config(&self) -> &EnvConfig {
        &self.config
    }

    /// The robot simulated.
    pub fn robot(&self) -> &SimulatedRobot {
        &self.config.robot
    }

    /// The robot's geometry.
    pub fn geometry(&self) -> &RobotGeometry {
        self.config.robot.geometry()
    }

    /// The robot's action lattice.
    pub fn lattice(&self) -> &ActionLattice {
        self.config.robot.lattice()
    }

    /// How far any part of the robot reaches horizontally from its centre, in any pose.
    pub(crate) fn reach_m(&self) -> f32 {
        self.reach_m
    }

    /// The obstacles.
    pub fn obstacles(&self) -> &ObstacleSet {
        &self.obstacles
    }

    /// Distance from the body centre to the target.
    pub fn distance_to_target_m(&self) -> f32 {
        (self.target - self.state.position).norm()
    }

    /// Applies one action.
    pub fn step(&mut self, action: Action) -> Result<StepOutcome, EpisodeOver> {
        if self.status.is_done() {
            return Err(EpisodeOver);
        }
        let before_m = self.distance_to_target_m();
        let next = self.state.after(action);
        let mut placed = None;
        let invalid = self.check_placing(&self.state, &next, &mut placed).err();
        match invalid {
            None => {
                // The parts at the new state, when the check placed them, start the next
                // step's check; parts of another state must not.
                if placed.is_some() {
                    self.parts_here = placed;
                } else if next != self.state {
                    self.parts_here = None;
                }
                self.state = next;
            }
            Some(InvalidAction::Collision) => self.collisions += 1,
            Some(_) => {}
        }
        self.steps += 1;
        let after_m = self.distance_to_target_m();
        self.status = if after_m <= self.config.success_radius_m {
            Status::Success
        } else if after_m > self.give_up_distance_m() {
            Status::TooFar
        } else if self.steps >= self.config.max_steps {
            Status::StepLimit
        } else {
            Status::Running
        };
        Ok(StepOutcome {
            reward: RewardTerms::with_invalid_reward(
                before_m,
                after_m,
                invalid.is_some(),
                self.config.invalid_reward,
            ),
            invalid,
            status: self.status,
        })
    }

    /// Writes the current observation into `out` (no allocation).
    pub fn observe(&self, out: &mut Observation) {
        height_map::render(
            self.obstacles.boxes(),
            self.state.position,
            self.state.yaw_rad(),
            &mut out.height_map,
        );
        let legs = self.state.leg_config(self.config.robot.geometry());
        let target = self.state.world_to_robot(self.target);
        out.state = [legs.clearance_m, legs.track_m, target.x, target.y];
    }

    /// The height map around the robot aligned with the world's axes, not the robot's (an
    /// elevation map kept in the odometry frame, as a local planner reads it:
    /// [`crate::local_plan`]), on layout `grid` into `out` (`grid.cells()` heights): row 0
    /// towards world +x, column 0 towards world +y, the robot at the centre.
    pub fn observe_world_aligned(&self, grid: height_map::MapGrid, out: &mut [f32]) {
        height_map::render_grid(self.obstacles.boxes(), self.state.position, 0.0, grid, out);
    }

    /// This episode as it stands (robot, target, steps, rules) in a world of other obstacles:
    /// what the robot perceives of the scene, for a search that may only use that
    /// ([`crate::local_plan`]).
    pub fn seen_as(&self, obstacles: ObstacleSet) -> Env {
        Env {
            obstacles,
            parts_here: None,
            ..self.clone()
        }
    }

    /// The height map around the robot on another layout than the policy's (`grid`, for
    /// example [`height_map::MapGrid::GUARD_FINE`] for the collision guard) into `out`, which
    /// must hold `grid.cells()` heights. [`GuardMap`] keeps such a map with its buffer.
    pub fn observe_grid(&self, grid: height_map::MapGrid, out: &mut [f32]) {
        height_map::render_grid(
            self.obstacles.boxes(),
            self.state.position,
            self.state.yaw_rad(),
            grid,
            out,
        );
    }
}
