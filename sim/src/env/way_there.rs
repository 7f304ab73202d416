//! The way there: the proof that a step's whole motion keeps every part of the robot clear of
//! the obstacles ([`Env::check_transition`]), and the bound on how far any point of the robot
//! moves in a step that the proof rests on ([`Env::motion_bound_m`]).

use super::way_proof::{prove_way, ProofPose, WayClearance};
use super::{Env, InvalidAction, SweptCollision};
use crate::collision::{place_parts, Part, RobotParts, PART_COUNT};
use crate::robot::SimulatedRobot;
use crate::state::RobotState;
use nalgebra::Point2;
use wheelleg_runtime::leg::{IkError, LegConfig};
use wheelleg_runtime::robot::RobotGeometry;

/// Pieces the knee's curved path is measured in by [`Env::motion_bound_m`].
const LEG_PATH_PIECES: u32 = 16;

/// Padding of the measured leg speed for how it varies between the pieces: near full stretch
/// the knee speeds up sharply. `sim/tests/swept_motion.rs` measures every lattice leg
/// transition at 200 pieces: the fastest comes to 0.80 of the padded bound (0.96 with a 1.25
/// padding, so 1.5).
const LEG_PATH_SAFETY: f32 = 1.5;

impl Env {
    /// Whether the step from `from` to `to` is valid: the end pose reachable by the legs and
    /// inside the arena, and no part of the robot touching an obstacle at the end pose **or
    /// anywhere on the way** (the straight path the controller drives:
    /// [`Env::pose_between`]).
    ///
    /// The way is proven clear, not sampled: a pose at clearance `d` from every obstacle keeps
    /// the stretch of motion within `d / D` of it clear, where `D` bounds how far any point of
    /// the robot moves over the whole step ([`Env::motion_bound_m`]). The step is bisected
    /// until every stretch is covered this way; a pose that touches is a collision, and so is a
    /// stretch shorter than [`GRAZE_TOLERANCE_M`](super::GRAZE_TOLERANCE_M) of motion that
    /// still cannot be proven clear (the robot would graze an obstacle within that tolerance).
    pub fn check_transition(
        &self,
        from: &RobotState,
        to: &RobotState,
    ) -> Result<(), InvalidAction> {
        self.check_placing(from, to, &mut None)
    }

    /// [`Env::check_transition`], also handing back in `placed` the robot's parts at `to` when
    /// it placed them and accepted the step (the next step starts there: [`Env::step`] keeps
    /// them). An out-parameter, not a returned value: the parts are a kilobyte, and most steps
    /// (far from obstacles) should not move one around.
    pub(super) fn check_placing(
        &self,
        from: &RobotState,
        to: &RobotState,
        placed: &mut Option<RobotParts>,
    ) -> Result<(), InvalidAction> {
        let p = to.position;
        if p.x < self.arena_min.x
            || p.y < self.arena_min.y
            || p.x > self.arena_max.x
            || p.y > self.arena_max.y
        {
            return Err(InvalidAction::OutOfBounds);
        }
        let legs = to.leg_config(self.config.robot.geometry());
        self.config
            .robot
            .geometry()
            .leg_ik(legs)
            .map_err(InvalidAction::Impossible)?;
        // Most steps are far from every obstacle: one box test then settles them, without
        // placing the robot's 13 parts. The box spans both ends, so it holds every pose on the
        // way too.
        if !self
            .obstacles
            .any_within_span(from.position, p, self.reach_m)
        {
            return Ok(());
        }
        let end = RobotParts::new(self.config.robot.geometry(), p, to.yaw_rad(), legs)
            .map_err(InvalidAction::Impossible)?;
        if self.obstacles.may_touch(&end.aabb()) && self.obstacles.collides(&end) {
            return Err(InvalidAction::Collision);
        }
        if from != to {
            self.check_way(from, to, &end)?;
        }
        *placed = Some(end);
        Ok(())
    }

    /// The way from `from` to `to`, the end pose `end` already found clear (see
    /// [`Env::check_transition`]).
    fn check_way(
        &self,
        from: &RobotState,
        to: &RobotState,
        end: &RobotParts,
    ) -> Result<(), InvalidAction> {
        let bound_m = self
            .motion_bound_m(from, to)
            .map_err(InvalidAction::Impossible)?;
        // The start is where the last accepted step ended, most of the time: its parts are
        // kept (the same values `pose_between(from, to, 0.0)` computes).
        let placed;
        let start = match &self.parts_here {
            Some(parts) if *from == self.state => parts,
            _ => {
                placed = self
                    .pose_between(from, to, 0.0)
                    .map_err(InvalidAction::Impossible)?;
                &placed
            }
        };
        if !self.obstacles.sweep_may_touch(start, end, 0.5 * bound_m) {
            return Ok(());
        }
        self.prove_way_clear(from, to, bound_m, start, end)
    }

    /// Bisects the step until the clearance at the poses covers every stretch between them
    /// ([`prove_way`], with the simulator's values: [`SimulatorClearance`]).
    fn prove_way_clear(
        &self,
        from: &RobotState,
        to: &RobotState,
        bound_m: f32,
        start: &RobotParts,
        end: &RobotParts,
    ) -> Result<(), InvalidAction> {
        prove_way(
            &mut SimulatorClearance {
                env: self,
                from,
                to,
                start,
                end,
                latest: None,
            },
            bound_m,
        )
    }

    /// The robot's parts at fraction `t` of the step from `from` to `to` (0 = start, 1 = end):
    /// position on the straight line, heading turning steadily the short way, legs on the
    /// straight line in (clearance, track). This is the path
    /// `wheelleg_runtime::motion::StepMotion` drives and a controlled stop rests on. Fails when
    /// the legs cannot take the in-between configuration.
    pub fn pose_between(
        &self,
        from: &RobotState,
        to: &RobotState,
        t: f32,
    ) -> Result<RobotParts, IkError> {
        let (position, yaw_rad, legs) = self.between(from, to, t);
        RobotParts::new(self.config.robot.geometry(), position, yaw_rad, legs)
    }

    /// [`Env::pose_between`] without the parts' bounding boxes (the same parts), for the
    /// planner's bounds on clearance.
    pub(crate) fn parts_between(
        &self,
        from: &RobotState,
        to: &RobotState,
        t: f32,
    ) -> Result<[Part; PART_COUNT], IkError> {
        let (position, yaw_rad, legs) = self.between(from, to, t);
        place_parts(self.config.robot.geometry(), position, yaw_rad, legs)
    }

    /// The body position, heading and legs at fraction `t` of the step (see
    /// [`Env::pose_between`]).
    fn between(&self, from: &RobotState, to: &RobotState, t: f32) -> (Point2<f32>, f32, LegConfig) {
        let (legs0, legs1) = (
            from.leg_config(self.config.robot.geometry()),
            to.leg_config(self.config.robot.geometry()),
        );
        let legs = LegConfig {
            clearance_m: legs0.clearance_m + t * (legs1.clearance_m - legs0.clearance_m),
            track_m: legs0.track_m + t * (legs1.track_m - legs0.track_m),
        };
        (
            from.position + t * (to.position - from.position),
            from.yaw_rad() + t * from.yaw_turn_rad_to(to),
            legs,
        )
    }

    /// A bound on how fast any point of the robot moves over the step from `from` to `to`, in
    /// metres per whole step: over any fraction `f` of the step no point moves farther than
    /// `f` times this. Three motions add up:
    /// - the body centre's straight line;
    /// - the turn: no point is farther than the horizontal reach from the turning axis;
    /// - the legs in the body frame (the body rising or sinking, knees and wheels moving as
    ///   the leg IK follows the interpolated (clearance, track)). The knee moves on a curve, so
    ///   its path is measured at [`LEG_PATH_PIECES`] pieces and padded by
    ///   [`LEG_PATH_SAFETY`]; `sim/tests/swept_motion.rs` checks the bound against finely sampled
    ///   paths over every leg transition of the lattice.
    ///
    /// Every other point of a part is a fixed combination of these (capsules between hip,
    /// knee and wheel; the wheel and body turning with the body), so it moves no farther.
    pub fn motion_bound_m(&self, from: &RobotState, to: &RobotState) -> Result<f32, IkError> {
        let travel_m = (to.position - from.position).norm();
        let turn_m = self.reach_m * from.yaw_turn_rad_to(to).abs();
        let leg_m = match LegMotionTable::for_robot(&self.config.robot).get(from, to) {
            Some(leg_m) => leg_m,
            None => leg_motion_m(
                self.config.robot.geometry(),
                from.leg_config(self.config.robot.geometry()),
                to.leg_config(self.config.robot.geometry()),
            )?,
        };
        Ok(travel_m + turn_m + leg_m)
    }

    /// Whether the whole motion from `from` to `to` keeps `margin_m` from every obstacle (0:
    /// does not touch), judged at `samples` + 1 evenly spaced poses of the path
    /// ([`Env::pose_between`]), both ends included. Reports the first fraction that comes too
    /// close. [`Env::check_transition`] already proves every accepted step touches nothing on
    /// the way; this sampled check with a margin is for the closed loop, where the real robot
    /// strays from the ideal path (tracking, odometry drift) and a fault can stop it anywhere
    /// along a step (50 samples = one per control tick of a 0.5 s step at 100 Hz), and for
    /// tests that check the proof against sampling.
    pub fn check_swept(
        &self,
        from: &RobotState,
        to: &RobotState,
        samples: u32,
        margin_m: f32,
    ) -> Result<(), SweptCollision> {
        let reach_m = self.reach_m + margin_m.max(0.0);
        if !self
            .obstacles
            .any_within_span(from.position, to.position, reach_m)
        {
            return Ok(());
        }
        let samples = samples.max(1);
        for i in 0..=samples {
            let t = i as f32 / samples as f32;
            let parts = self.pose_between(from, to, t);
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
}

/// The simulator's clearance values for [`prove_way`]: a stretch is first tried with a cheap
/// lower bound on it (`ObstacleSet::clearance_lower_bound_m`, from box gaps), and only a stretch
/// those do not prove asks for parry's exact values at its ends (`ObstacleSet::clearance_m`):
/// the verdict is the one the exact values alone give, found with fewer of parry's queries.
struct SimulatorClearance<'a> {
    env: &'a Env,
    from: &'a RobotState,
    to: &'a RobotState,
    /// The robot's parts at the start and the end, already placed.
    start: &'a RobotParts,
    end: &'a RobotParts,
    /// The latest in-between pose placed: the stretch from the pose before it is tried next,
    /// and may need its exact clearance.
    latest: Option<(f32, RobotParts)>,
}

impl SimulatorClearance<'_> {
    /// The parts at fraction `t`, placed again only when they are not at hand.
    fn parts(&mut self, t: f32) -> Result<&RobotParts, InvalidAction> {
        if t == 0.0 {
            return Ok(self.start);
        }
        if t == 1.0 {
            return Ok(self.end);
        }
        if !matches!(&self.latest, Some((at, _)) if *at == t) {
            let parts = self
                .env
                .pose_between(self.from, self.to, t)
                .map_err(InvalidAction::Impossible)?;
            self.latest = Some((t, parts));
        }
        Ok(&self.latest.as_ref().expect("just placed").1)
    }
}

impl WayClearance for SimulatorClearance<'_> {
    type Refusal = InvalidAction;

    fn cheap_m(&mut self, t: f32, cap_m: f32) -> Result<f32, InvalidAction> {
        let env = self.env;
        Ok(env.obstacles.clearance_lower_bound_m(self.parts(t)?, cap_m))
    }

    fn exact_m(&mut self, pose: &ProofPose) -> Result<Option<f32>, InvalidAction> {
        let env = self.env;
        Ok(env.obstacles.clearance_m(self.parts(pose.t)?, pose.cap_m))
    }

    fn touches(&self) -> InvalidAction {
        InvalidAction::Collision
    }
}

/// The legs' term of [`Env::motion_bound_m`]: how far any point of a leg (or the body, as it
/// rises or sinks) moves in the body frame as (clearance, track) goes from `legs0` to `legs1`
/// on the straight line, measured in [`LEG_PATH_PIECES`] pieces and padded by
/// [`LEG_PATH_SAFETY`].
fn leg_motion_m(
    geometry: &RobotGeometry,
    legs0: LegConfig,
    legs1: LegConfig,
) -> Result<f32, IkError> {
    if legs0 == legs1 {
        return Ok(0.0);
    }
    // One leg stands for all four: they mirror each other.
    let leg = wheelleg_runtime::robot::LegId::FrontLeft;
    let mut previous: Option<[nalgebra::Point3<f32>; 4]> = None;
    let mut longest_piece_m = 0.0f32;
    for piece in 0..=LEG_PATH_PIECES {
        let t = piece as f32 / LEG_PATH_PIECES as f32;
        let legs = LegConfig {
            clearance_m: legs0.clearance_m + t * (legs1.clearance_m - legs0.clearance_m),
            track_m: legs0.track_m + t * (legs1.track_m - legs0.track_m),
        };
        let points = geometry.leg_points(leg, geometry.leg_ik(legs)?);
        let lift = nalgebra::Vector3::z() * geometry.body_centre_height_m(legs.clearance_m);
        let now = [
            points.hip + lift,
            points.knee + lift,
            points.wheel_mount + lift,
            points.wheel + lift,
        ];
        if let Some(before) = previous {
            for (a, b) in before.iter().zip(&now) {
                longest_piece_m = longest_piece_m.max((b - a).norm());
            }
        }
        previous = Some(now);
    }
    Ok(LEG_PATH_SAFETY * LEG_PATH_PIECES as f32 * longest_piece_m)
}

/// [`leg_motion_m`] for every lattice leg pose of a robot and every leg step from
/// it (clearance and track each by -1, 0 or +1 steps), worked out once: the bound needs the
/// legs' IK at 17 poses, which cost as much as the rest of a step's check near obstacles. The
/// entries are the very values [`leg_motion_m`] returns (same inputs, same arithmetic), so a
/// step's bound is the same bit for bit with or without the table.
struct LegMotionTable {
    /// Lowest clearance and track steps held.
    clearance_min: i32,
    track_min: i32,
    /// Clearance and track steps held: `clearance_min..clearance_min + clearance_count`.
    clearance_count: i32,
    track_count: i32,
    /// Per (clearance, track, leg step): the legs' motion, or `None` where the IK fails on the
    /// way (the exact function then says why).
    leg_m: Vec<Option<f32>>,
}

impl LegMotionTable {
    /// The table for `robot`, built on first use.
    fn for_robot(robot: &SimulatedRobot) -> &'static LegMotionTable {
        static TABLES: crate::PerRobot<LegMotionTable> = crate::PerRobot::new();
        TABLES.get(robot, LegMotionTable::new)
    }

    fn new(robot: &SimulatedRobot) -> Self {
        let (geometry, lattice) = (robot.geometry(), robot.lattice());
        // Every step count whose (clearance, track) lies within the legs' ranges, one more
        // each side for rounding.
        let steps = |range: [f32; 2], default_m: f32, step_m: f32| {
            let low = ((range[0] - default_m) / step_m).floor() as i32 - 1;
            let high = ((range[1] - default_m) / step_m).ceil() as i32 + 1;
            (low, high - low + 1)
        };
        let (clearance_min, clearance_count) = steps(
            geometry.clearance_range_m,
            geometry.default_clearance_m,
            lattice.clearance_step_m,
        );
        let (track_min, track_count) = steps(
            geometry.track_range_m,
            geometry.default_track_m,
            lattice.track_step_m,
        );
        let mut leg_m = Vec::with_capacity((clearance_count * track_count * 9) as usize);
        for clearance_steps in clearance_min..clearance_min + clearance_count {
            for track_steps in track_min..track_min + track_count {
                let from = RobotState {
                    position: Point2::origin(),
                    yaw_steps: 0,
                    clearance_steps,
                    track_steps,
                    lattice: *lattice,
                };
                for d_clearance in -1..=1 {
                    for d_track in -1..=1 {
                        let to = RobotState {
                            clearance_steps: clearance_steps + d_clearance,
                            track_steps: track_steps + d_track,
                            ..from
                        };
                        leg_m.push(
                            leg_motion_m(
                                geometry,
                                from.leg_config(geometry),
                                to.leg_config(geometry),
                            )
                            .ok(),
                        );
                    }
                }
            }
        }
        LegMotionTable {
            clearance_min,
            track_min,
            clearance_count,
            track_count,
            leg_m,
        }
    }

    /// The legs' motion from `from` to `to`, when the table holds it.
    fn get(&self, from: &RobotState, to: &RobotState) -> Option<f32> {
        let (c, t) = (
            from.clearance_steps - self.clearance_min,
            from.track_steps - self.track_min,
        );
        let (dc, dt) = (
            to.clearance_steps - from.clearance_steps,
            to.track_steps - from.track_steps,
        );
        if !(0..self.clearance_count).contains(&c)
            || !(0..self.track_count).contains(&t)
            || dc.abs() > 1
            || dt.abs() > 1
        {
            return None;
        }
        let index = ((c * self.track_count + t) * 9 + (dc + 1) * 3 + (dt + 1)) as usize;
        self.leg_m[index]
    }
}

/// A bound on how far any robot part reaches horizontally from the body centre, in any pose:
/// [`horizontal_reach_at_track_m`] at the widest track.
pub(crate) fn horizontal_reach_m(geometry: &RobotGeometry) -> f32 {
    horizontal_reach_at_track_m(geometry, geometry.track_range_m[1])
}

/// A bound on how far any robot part reaches horizontally from the body centre at a track of
/// `track_m` or narrower: the body's corner, a wheel, a knee (at most a thigh's length outboard
/// of its hip) or a shank's end at the wheel mount (the wheel offset inboard of the wheel's
/// centre), plus the largest part radius.
pub(crate) fn horizontal_reach_at_track_m(geometry: &RobotGeometry, track_m: f32) -> f32 {
    let body = (0.5 * geometry.body_length_m).hypot(0.5 * geometry.body_width_m);
    let wheel = (geometry.hip_x_m + geometry.wheel_radius_m)
        .hypot(0.5 * track_m + 0.5 * geometry.wheel_width_m);
    let knee = geometry
        .hip_x_m
        .hypot(geometry.hip_y_m + geometry.thigh_m + geometry.link_radius_m);
    let mount = (geometry.hip_x_m + geometry.link_radius_m)
        .hypot(0.5 * track_m - geometry.wheel_offset_m + geometry.link_radius_m);
    body.max(wheel).max(knee).max(mount) + 0.01
}
