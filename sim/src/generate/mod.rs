//! Scene generators: one simple scene family per behaviour, each built so that the behaviour is
//! necessary, and complex scenes that mix every obstacle kind.
//!
//! Every scene starts the robot on its start lattice (whole move steps, 0.05 m for the shipped
//! robot) with a random yaw on its yaw lattice (5 degrees) and puts the target 0.5 to 1.0 m
//! ahead along world x. Behaviour scenes put a *fence* across
//! the whole arena between start and target, with exactly one kind of passage in it, so the only
//! way through is the behaviour (docs/simulator.md has the cross-section arithmetic):
//!
//! - lift over: bars lengthwise on every cell; the 0.17 m gaps between bars are narrower than
//!   the robot at any track, so it must straddle a bar, body lifted above 0.15 m;
//! - spread over: a slab, then blocks two cells away on either side, three rows deep; the lanes
//!   beside the slab are too narrow for the robot, so it must straddle the slab with the legs
//!   spread. Three rows because a shallower slab can be straddled at the default track: turned
//!   sideways over one row's 0.25 m, or diagonally over two rows' 0.5 m;
//! - squeeze: blocks on every cell but one, two rows deep: a 0.30 m wide corridor that the
//!   default pose (0.40 m wide) does not fit through (a single 0.20 m row can be threaded
//!   diagonally, one wheel at a time);
//! - around: one block, or two side by side, on the straight line to the target;
//! - straight: no obstacles.
//!
//! Composed scenes (`composed.rs`) put those fences amid clutter: one or two fences, mixed kinds,
//! clutter off the passage's lane, targets in and beyond the passages. Exit scenes (`exit.rs`)
//! are behaviour scenes whose target stands just past the fence, beside the opening.

mod complex;
mod composed;
mod exit;
mod fence;
mod fit;
pub use composed::{ComposedEnding, ComposedVariant, COMPOSED_PAIRS};
pub use exit::exit_scene;
pub use fit::{SceneRobot, FENCE_MARGIN_M};

use complex::{complex_scene, random_obstacle};
use fence::{behaviour_scene, fence_cells, fence_rows, staged_scene};

use crate::obstacle::GRID_CELL_M;
use crate::scenario::Scenario;
use crate::state::RobotState;
use nalgebra::Point2;
use rand::Rng;

/// The five behaviours of the paper's secondary policies.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Behaviour {
    /// Drive straight to the target; nothing in the way.
    Straight,
    /// Drive around one or two blocks.
    Around,
    /// Lift the body and straddle a bar.
    LiftOver,
    /// Spread the legs (lowering the body) and straddle a slab.
    SpreadOver,
    /// Narrow the legs and squeeze through a gap between blocks.
    Squeeze,
}

impl Behaviour {
    /// All behaviours, in training order (straight first: the others start from it).
    pub const ALL: [Behaviour; 5] = [
        Behaviour::Straight,
        Behaviour::Around,
        Behaviour::LiftOver,
        Behaviour::SpreadOver,
        Behaviour::Squeeze,
    ];

    /// Name used on the command line and in scenario names.
    pub const fn name(self) -> &'static str {
        match self {
            Behaviour::Straight => "straight",
            Behaviour::Around => "around",
            Behaviour::LiftOver => "lift",
            Behaviour::SpreadOver => "spread",
            Behaviour::Squeeze => "squeeze",
        }
    }

    /// The behaviour named `name` ([`Behaviour::name`]).
    pub fn from_name(name: &str) -> Option<Behaviour> {
        Behaviour::ALL.into_iter().find(|b| b.name() == name)
    }

    /// Whether the behaviour's scenes put a fence across the arena (lift, spread, squeeze).
    pub const fn has_fence(self) -> bool {
        matches!(
            self,
            Behaviour::LiftOver | Behaviour::SpreadOver | Behaviour::Squeeze
        )
    }
}

/// What to generate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SceneKind {
    /// A simple scene for one behaviour.
    Behaviour(Behaviour),
    /// A complex scene: 1 to 8 obstacles of any kind.
    Complex,
    /// One or two fences amid clutter (`composed.rs`): a behaviour needed where other
    /// obstacles stand.
    Composed,
}

impl SceneKind {
    /// All kinds, behaviours first.
    pub const ALL: [SceneKind; 7] = [
        SceneKind::Behaviour(Behaviour::Straight),
        SceneKind::Behaviour(Behaviour::Around),
        SceneKind::Behaviour(Behaviour::LiftOver),
        SceneKind::Behaviour(Behaviour::SpreadOver),
        SceneKind::Behaviour(Behaviour::Squeeze),
        SceneKind::Complex,
        SceneKind::Composed,
    ];

    /// Name used on the command line.
    pub const fn name(self) -> &'static str {
        match self {
            SceneKind::Behaviour(b) => b.name(),
            SceneKind::Complex => "complex",
            SceneKind::Composed => "composed",
        }
    }

    /// Parses a command-line name.
    pub fn from_name(name: &str) -> Option<SceneKind> {
        SceneKind::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// Index of the grid cell containing `value_m`.
fn cell_index(value_m: f32) -> i32 {
    (value_m / GRID_CELL_M).floor() as i32
}

/// Start and target of a scene, with the fence cell's x index for scenes that need one.
struct Layout {
    start: RobotState,
    target: Point2<f32>,
}

/// How a scene's start yaw is drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum StartYaw {
    /// Any yaw on the robot's yaw lattice: the task as specified.
    #[default]
    Any,
    /// The body's long axis along world x (facing the target or away from it), give or take
    /// `within_deg`, on the robot's yaw lattice. Lift, spread and squeeze passages are only
    /// passable lined up with the fence, and a policy that starts from the straight-line one
    /// has never turned: from any yaw it must find a turn of up to 90 degrees (18 steps) and
    /// the behaviour together before the first success. A training curriculum can first
    /// teach the behaviour lined up and leave the turning to the primary policy.
    AlongX {
        /// Largest deviation from the world x axis, degrees.
        within_deg: f32,
    },
}

impl StartYaw {
    /// `Any` from 90 degrees on (every heading is within 90 degrees of one of the two along
    /// x), `AlongX` below.
    pub fn within_deg(within_deg: f32) -> StartYaw {
        if within_deg >= 90.0 {
            StartYaw::Any
        } else {
            StartYaw::AlongX { within_deg }
        }
    }

    fn draw(self, robot: &SceneRobot, rng: &mut impl Rng) -> i32 {
        let per_turn = robot.robot().yaw_steps_per_turn();
        match self {
            StartYaw::Any => rng.random_range(0..per_turn),
            StartYaw::AlongX { within_deg } => {
                let steps = (within_deg.max(0.0) / robot.robot().lattice().yaw_step_deg) as i32;
                let base = if rng.random_bool(0.5) {
                    0
                } else {
                    per_turn / 2
                };
                base + rng.random_range(-steps..=steps)
            }
        }
    }
}

/// Random start on the start lattice within 0.10 m of the origin, yaw as `start_yaw`; the
/// target `min_ahead_m..=1.0` ahead along x.
fn layout(robot: &SceneRobot, rng: &mut impl Rng, min_ahead_m: f32, start_yaw: StartYaw) -> Layout {
    let step_m = robot.robot().lattice().move_step_m as f64;
    let near = (0.10 / step_m).round() as i32;
    let x = robot.on_start_lattice(rng.random_range(-near..=near));
    let y = robot.on_start_lattice(rng.random_range(-near..=near));
    let yaw_steps = start_yaw.draw(robot, rng);
    let min_k = ((min_ahead_m.max(0.5) as f64) / step_m).ceil() as i32;
    let max_k = (1.0 / step_m).round() as i32;
    let k = rng.random_range(min_k.min(max_k)..=max_k);
    let start = RobotState::new(Point2::new(x, y), yaw_steps, robot.robot().lattice());
    Layout {
        target: Point2::new(robot.on_start_lattice(robot.start_lattice_index(x) + k), y),
        start,
    }
}

/// Generates one scene of `kind` for `robot`. Scenes that come out invalid (robot starting inside
/// an obstacle, target unreachable by construction) are redrawn, so the result always validates.
/// A fence the robot lacks the behaviour for ([`SceneRobot::has`]) is still built: callers
/// leave such kinds out, saying why.
pub fn generate(robot: &SceneRobot, kind: SceneKind, rng: &mut impl Rng, name: String) -> Scenario {
    generate_with_start(robot, kind, StartYaw::Any, rng, name)
}

/// [`generate`] with the start yaw drawn as `start_yaw`.
pub fn generate_with_start(
    robot: &SceneRobot,
    kind: SceneKind,
    start_yaw: StartYaw,
    rng: &mut impl Rng,
    name: String,
) -> Scenario {
    loop {
        let scenario = match kind {
            SceneKind::Behaviour(b) => behaviour_scene(robot, b, rng, name.clone(), start_yaw).0,
            SceneKind::Complex => complex_scene(robot, rng, name.clone(), start_yaw),
            SceneKind::Composed => composed::composed_scene(robot, rng, name.clone(), start_yaw),
        };
        if scenario.validate(robot.robot()).is_ok() && target_is_free(robot, &scenario) {
            return scenario;
        }
    }
}

/// [`generate_with_start`] with the start part-way along the start-stage curriculum (a reverse
/// curriculum over start states): `stage` 1 (or more) is the task as specified, the very same
/// scene [`generate_with_start`] draws from the same `rng`; below 1 the obstacles and target stay
/// as drawn and only the start moves towards the passage:
///
/// - `stage` 0: lined up with the passage (facing along x, towards or away from the target, as
///   the drawn yaw was nearer), on its centre line, inside its first row, legs already in the
///   pose that passes ([`SceneRobot::passing_legs`]: spread wide and low, narrow, lifted; beside the
///   around block in the default pose);
/// - from 0 to 0.5 the start moves back along x, still lined up and in the passing pose, to
///   the drawn start's x;
/// - from 0.5 to 1 the legs go back to the default pose, the start slides sideways to the
///   drawn y, and the yaw turns from lined up to the drawn yaw (so the yaw freedom grows back
///   to `start_yaw`'s), each by the same fraction, rounded to the lattices.
///
/// A start that would collide (or stand within 0.2 m of the target) is moved back along x a
/// step at a time; if that does not help within 20 steps the drawn start is kept. Every scene
/// validates. Straight and complex scenes have no passage and are returned as drawn.
pub fn generate_staged(
    robot: &SceneRobot,
    kind: SceneKind,
    start_yaw: StartYaw,
    stage: f32,
    rng: &mut impl Rng,
    name: String,
) -> Scenario {
    let behaviour = match kind {
        SceneKind::Behaviour(b) if b != Behaviour::Straight && stage < 1.0 => b,
        _ => return generate_with_start(robot, kind, start_yaw, rng, name),
    };
    // The same draws, in the same order, as `generate_with_start`.
    loop {
        let (scenario, passage) = behaviour_scene(robot, behaviour, rng, name.clone(), start_yaw);
        if scenario.validate(robot.robot()).is_ok() && target_is_free(robot, &scenario) {
            return staged_scene(robot, &scenario, behaviour, passage, stage).unwrap_or(scenario);
        }
    }
}

/// Generates `count` scenes named `{kind}-{i}`.
pub fn generate_many(
    robot: &SceneRobot,
    kind: SceneKind,
    rng: &mut impl Rng,
    count: usize,
) -> Vec<Scenario> {
    (0..count)
        .map(|i| generate(robot, kind, rng, format!("{}-{i}", kind.name())))
        .collect()
}

/// Whether the robot could stand at the target: some yaw in the default pose or one of three
/// poses across the lattice (lifted and narrowed, spread and low, squeezed) does not collide.
/// Scenes whose target lies inside an obstacle are useless.
fn target_is_free(robot: &SceneRobot, scenario: &Scenario) -> bool {
    let obstacles = crate::collision::ObstacleSet::new(&scenario.obstacles);
    let geometry = robot.geometry();
    let lattice = robot.robot().lattice();
    // Metres from the default pose, to the nearest leg step: (0.12, 0.36), (0.18, 0.24),
    // (0.08, 0.56) and (0.10, 0.16) m of clearance and track for the shipped robot. A pose
    // the legs cannot take on another lattice comes a step nearer the default until they can.
    let poses = [(0.0, 0.0), (0.06, -0.12), (-0.04, 0.20), (-0.02, -0.20)].map(|(c, t)| {
        let mut steps = (
            (c / lattice.clearance_step_m).round() as i32,
            (t / lattice.track_step_m).round() as i32,
        );
        loop {
            let legs = RobotState {
                clearance_steps: steps.0,
                track_steps: steps.1,
                ..RobotState::new(scenario.target, 0, lattice)
            }
            .leg_config(geometry);
            if steps == (0, 0) || geometry.is_reachable(legs) {
                return legs;
            }
            steps = (steps.0 - steps.0.signum(), steps.1 - steps.1.signum());
        }
    });
    // Every 15 degrees over half a turn (the robot is symmetric front to back).
    let every = (15.0 / lattice.yaw_step_deg).round().max(1.0) as usize;
    let per_turn = robot.robot().yaw_steps_per_turn();
    (0..per_turn / 2).step_by(every).any(|yaw| {
        poses.iter().any(|&legs| {
            crate::collision::RobotParts::new(
                geometry,
                scenario.target,
                (yaw as f32 * lattice.yaw_step_deg).to_radians(),
                legs,
            )
            .is_ok_and(|parts| !obstacles.collides(&parts))
        })
    })
}
