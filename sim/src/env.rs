//! One episode of the navigation task: reset to a scenario, step with actions, observe.
//!
//! An invalid action (collision, impossible leg pose, leaving the arena) is undone: the state
//! stays as before the action, the step counts, and the reward carries the invalid penalty.
//! Collision is checked at the end pose and, when the robot is near an obstacle, at the
//! half-way pose too, so that no part can jump through a thin obstacle within one step.

use crate::collision::{ObstacleSet, RobotParts};
use crate::height_map::{self, HeightMap};
use crate::reward::RewardTerms;
use crate::scenario::{Scenario, ScenarioError};
use crate::state::RobotState;
use nalgebra::{Point2, Vector2};
use wheelleg_runtime::action::{Action, CLEARANCE_STEP_M, TRACK_STEP_M, YAW_STEP_DEG};
use wheelleg_runtime::leg::{IkError, LegConfig};
use wheelleg_runtime::observation::STATE_LEN;
use wheelleg_runtime::robot::{RobotGeometry, WHEELLEG};

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
}

impl Default for EnvConfig {
    fn default() -> Self {
        EnvConfig {
            max_steps: 100,
            success_radius_m: 0.05,
            give_up_margin_m: 0.5,
            arena_margin_m: 0.6,
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
    geometry: RobotGeometry,
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
}

/// Stepping an episode that is over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EpisodeOver;

impl Env {
    /// Starts an episode of `scenario` with the project's robot.
    pub fn new(scenario: &Scenario, config: EnvConfig) -> Result<Self, ScenarioError> {
        Env::with_geometry(scenario, config, WHEELLEG)
    }

    /// Starts an episode with a given robot geometry.
    pub fn with_geometry(
        scenario: &Scenario,
        config: EnvConfig,
        geometry: RobotGeometry,
    ) -> Result<Self, ScenarioError> {
        scenario.validate(&geometry)?;
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
            geometry,
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
            reach_m: horizontal_reach_m(&geometry),
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

    /// The robot geometry.
    pub fn geometry(&self) -> &RobotGeometry {
        &self.geometry
    }

    /// The obstacles.
    pub fn obstacles(&self) -> &ObstacleSet {
        &self.obstacles
    }

    /// Distance from the body centre to the target.
    pub fn distance_to_target_m(&self) -> f32 {
        (self.target - self.state.position).norm()
    }

    /// Whether `state` is a valid place for the robot (reachable legs, inside the arena, no
    /// collision), given it comes from `from` in one step.
    pub fn check_transition(
        &self,
        from: &RobotState,
        to: &RobotState,
    ) -> Result<(), InvalidAction> {
        let p = to.position;
        if p.x < self.arena_min.x
            || p.y < self.arena_min.y
            || p.x > self.arena_max.x
            || p.y > self.arena_max.y
        {
            return Err(InvalidAction::OutOfBounds);
        }
        let legs = to.leg_config(&self.geometry);
        self.geometry
            .leg_ik(legs)
            .map_err(InvalidAction::Impossible)?;
        // Most steps are far from every obstacle: one box test then settles them, without
        // placing the robot's 13 parts.
        if !self.obstacles.any_within(p, self.reach_m)
            && !self.obstacles.any_within(from.position, self.reach_m)
        {
            return Ok(());
        }
        let end = RobotParts::new(&self.geometry, p, to.yaw_rad(), legs)
            .map_err(InvalidAction::Impossible)?;
        if !self.obstacles.may_touch(&end.aabb()) {
            return Ok(());
        }
        if self.obstacles.collides(&end) {
            return Err(InvalidAction::Collision);
        }
        if from == to {
            return Ok(());
        }
        // Half-way pose of the motion: positions, yaw and leg pose interpolated.
        let from_legs = from.leg_config(&self.geometry);
        let mid_legs = LegConfig {
            clearance_m: 0.5 * (from_legs.clearance_m + legs.clearance_m),
            track_m: 0.5 * (from_legs.track_m + legs.track_m),
        };
        debug_assert!((legs.track_m - from_legs.track_m).abs() <= TRACK_STEP_M + 1e-6);
        debug_assert!((legs.clearance_m - from_legs.clearance_m).abs() <= CLEARANCE_STEP_M + 1e-6);
        let yaw_delta =
            (to.yaw_steps - from.yaw_steps + 1).rem_euclid(crate::state::YAW_STEPS_PER_TURN) - 1;
        let mid_yaw = from.yaw_rad() + 0.5 * (yaw_delta as f32 * YAW_STEP_DEG).to_radians();
        let mid = RobotParts::new(
            &self.geometry,
            from.position + 0.5 * (p - from.position),
            mid_yaw,
            mid_legs,
        )
        .map_err(InvalidAction::Impossible)?;
        if self.obstacles.collides(&mid) {
            return Err(InvalidAction::Collision);
        }
        Ok(())
    }

    /// Whether the whole motion from `from` to `to` keeps `margin_m` from every obstacle (0:
    /// does not touch), judged at `samples` + 1
    /// evenly spaced poses of the robot's path (position on the straight line, heading turning
    /// steadily, legs on the straight line in (clearance, track): the path
    /// `wheelleg_runtime::motion::StepMotion` drives and a controlled stop rests on), both ends
    /// included. [`Env::check_transition`] judges the start, half-way and end poses only, which
    /// is what training uses and what the planner plans with; this finer check is for the
    /// closed loop, where a fault can stop the robot anywhere along a step (50 samples = one
    /// per control tick of a 0.5 s step at 100 Hz); the margin covers how far the real robot
    /// strays from the ideal path (tracking, odometry drift). Reports the first fraction that
    /// comes too close.
    pub fn check_swept(
        &self,
        from: &RobotState,
        to: &RobotState,
        samples: u32,
        margin_m: f32,
    ) -> Result<(), SweptCollision> {
        let (p0, p1) = (from.position, to.position);
        let reach_m = self.reach_m + margin_m.max(0.0);
        if !self.obstacles.any_within(p0, reach_m) && !self.obstacles.any_within(p1, reach_m) {
            return Ok(());
        }
        let (legs0, legs1) = (
            from.leg_config(&self.geometry),
            to.leg_config(&self.geometry),
        );
        let yaw_delta =
            (to.yaw_steps - from.yaw_steps + 1).rem_euclid(crate::state::YAW_STEPS_PER_TURN) - 1;
        let yaw_delta_rad = (yaw_delta as f32 * YAW_STEP_DEG).to_radians();
        let samples = samples.max(1);
        for i in 0..=samples {
            let t = i as f32 / samples as f32;
            let legs = LegConfig {
                clearance_m: legs0.clearance_m + t * (legs1.clearance_m - legs0.clearance_m),
                track_m: legs0.track_m + t * (legs1.track_m - legs0.track_m),
            };
            let parts = RobotParts::new(
                &self.geometry,
                p0 + t * (p1 - p0),
                from.yaw_rad() + t * yaw_delta_rad,
                legs,
            );
            // A pose the legs cannot take is not a collision, but the motion is not safe to
            // stop in either: report it as colliding.
            let collides = parts.map_or(true, |parts| {
                if margin_m > 0.0 {
                    self.obstacles.within_margin(&parts, margin_m)
                } else {
                    self.obstacles.may_touch(&parts.aabb()) && self.obstacles.collides(&parts)
                }
            });
            if collides {
                return Err(SweptCollision { fraction: t });
            }
        }
        Ok(())
    }

    /// Applies one action.
    pub fn step(&mut self, action: Action) -> Result<StepOutcome, EpisodeOver> {
        if self.status.is_done() {
            return Err(EpisodeOver);
        }
        let before_m = self.distance_to_target_m();
        let next = self.state.after(action);
        let invalid = self.check_transition(&self.state, &next).err();
        match invalid {
            None => self.state = next,
            Some(InvalidAction::Collision) => self.collisions += 1,
            Some(_) => {}
        }
        self.steps += 1;
        let after_m = self.distance_to_target_m();
        self.status = if after_m <= self.config.success_radius_m {
            Status::Success
        } else if after_m > self.start_distance_m + self.config.give_up_margin_m {
            Status::TooFar
        } else if self.steps >= self.config.max_steps {
            Status::StepLimit
        } else {
            Status::Running
        };
        Ok(StepOutcome {
            reward: RewardTerms::new(before_m, after_m, invalid.is_some()),
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
        let legs = self.state.leg_config(&self.geometry);
        let target = self.state.world_to_robot(self.target);
        out.state = [legs.clearance_m, legs.track_m, target.x, target.y];
    }
}

/// A bound on how far any robot part reaches horizontally from the body centre, in any pose:
/// the body's corner, or a wheel at the widest track (the knees stay inside the wheels'
/// reach: they are at most a thigh's length outboard of the hips), plus the largest part radius.
fn horizontal_reach_m(geometry: &RobotGeometry) -> f32 {
    let body = (0.5 * geometry.body_length_m).hypot(0.5 * geometry.body_width_m);
    let wheel = (geometry.hip_x_m + geometry.wheel_radius_m)
        .hypot(0.5 * geometry.track_range_m[1] + 0.5 * geometry.wheel_width_m);
    let knee = geometry
        .hip_x_m
        .hypot(geometry.hip_y_m + geometry.thigh_m + geometry.link_radius_m);
    body.max(wheel).max(knee) + 0.01
}
