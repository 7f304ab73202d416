//! Proofs shared by the scenario and planner tests: that a fence is a barrier for a set of leg
//! configurations (a geometric argument over every pose near its rows), that scenes are
//! solvable (a plan replayed to success in a fresh episode), and the breadth-first reference
//! search a shortest plan must match.

// Each test crate that includes this module uses only some of its helpers.
#![allow(dead_code)]

use nalgebra::Point2;
use std::collections::{HashMap, VecDeque};
use wheelleg_runtime::action::{Action, COUNT};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::RobotGeometry;
use wheelleg_sim::collision::{ObstacleSet, RobotParts};
use wheelleg_sim::env::{Env, EnvConfig, Status};
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig};
use wheelleg_sim::robot::SimulatedRobot;
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;

/// Which (clearance steps, track steps) leg configurations a test allows.
pub type LegFilter = fn(i32, i32) -> bool;

/// The robots the scene proofs run for: the shipped one and `robots/strider.toml`, a larger
/// one whose passing poses differ (lift +2, squeeze -10 track steps with one clearance step
/// down).
pub fn robots() -> [(&'static str, SimulatedRobot); 2] {
    let strider = wheelleg_robot::RobotDescription::load(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../robots/strider.toml"
    )))
    .and_then(|d| SimulatedRobot::of(&d))
    .expect("robots/strider.toml");
    [("wheelleg", SimulatedRobot::SHIPPED), ("strider", strider)]
}

/// The episode settings for `robot`.
pub fn env_config(robot: &SimulatedRobot) -> EnvConfig {
    EnvConfig {
        robot: *robot,
        ..EnvConfig::default()
    }
}

/// Leg configurations on the action lattice (steps from the default pose, as
/// `RobotState::leg_config` places them) that the legs of `robot` can reach, filtered.
pub fn lattice_legs(robot: &SimulatedRobot, keep: impl Fn(i32, i32) -> bool) -> Vec<LegConfig> {
    let geometry = robot.geometry();
    let state = |clearance_steps, track_steps| RobotState {
        clearance_steps,
        track_steps,
        ..RobotState::new(Point2::origin(), 0, robot.lattice())
    };
    let mut out = Vec::new();
    for clearance_steps in -15..=15 {
        for track_steps in -15..=15 {
            let legs = state(clearance_steps, track_steps).leg_config(geometry);
            if keep(clearance_steps, track_steps) && geometry.is_reachable(legs) {
                out.push(legs);
            }
        }
    }
    out
}

/// Whether the fence is a barrier for the allowed leg configurations. Any way across the fence
/// carries the robot's front axle across the fence's first row, and its centre across the
/// fence's middle. If, with either of those points anywhere in a band one step wide around its
/// line, every lateral position across the arena (5 mm apart), every yaw and every allowed leg
/// configuration collides, no sequence of steps gets across.
pub fn fence_blocks(scene: &Scenario, geometry: &RobotGeometry, legs: &[LegConfig]) -> bool {
    let first_x = scene
        .obstacles
        .iter()
        .map(|o| o.centre.x)
        .fold(f32::NAN, f32::min);
    let last_x = scene
        .obstacles
        .iter()
        .map(|o| o.centre.x)
        .fold(f32::NAN, f32::max);
    free_pose_near_line(scene, geometry, legs, first_x, geometry.hip_x_m).is_none()
        || free_pose_near_line(scene, geometry, legs, 0.5 * (first_x + last_x), 0.0).is_none()
}

/// A pose that does not collide with the robot's point `ahead_m` in front of its centre within
/// 4 cm of the line x = `line_x`, if any: (that point's x, body centre y, yaw in degrees, legs).
pub fn free_pose_near_line(
    scene: &Scenario,
    geometry: &RobotGeometry,
    legs: &[LegConfig],
    line_x: f32,
    ahead_m: f32,
) -> Option<(f32, f32, f32, LegConfig)> {
    let obstacles = ObstacleSet::new(&scene.obstacles);
    // Across the arena: the box around start and target grown by its margin.
    let margin_m = EnvConfig::default().arena_margin_m;
    let low_m = scene.start.position.y.min(scene.target.y) - margin_m;
    let across = ((scene.start.position.y - scene.target.y).abs() + 2.0 * margin_m) / 0.005;
    for dx in -4..=4 {
        let x = line_x + 0.01 * dx as f32;
        for dy in 0..=across.round() as i32 {
            let y = low_m + 0.005 * dy as f32;
            for yaw_steps in 0..72 {
                let yaw = (yaw_steps as f32 * 5.0).to_radians();
                let centre = Point2::new(x - ahead_m * yaw.cos(), y - ahead_m * yaw.sin());
                for &l in legs {
                    let free = RobotParts::new(geometry, centre, yaw, l)
                        .is_ok_and(|p| !obstacles.collides(&p));
                    if free {
                        return Some((x, centre.y, yaw_steps as f32 * 5.0, l));
                    }
                }
            }
        }
    }
    None
}

/// Proves every scene solvable: `prefix` (actions taken first, each of which must be valid),
/// then a plan by the first of the weighted searches `configs` that finds one (the planner
/// replays what it returns in the simulator), and the whole sequence replayed to success in a fresh episode. Panics on a
/// scene it does not solve; returns per scene the states the plan passes through, start
/// included.
pub fn prove_solvable(
    scenes: &[Scenario],
    robot: &SimulatedRobot,
    prefix: impl Fn(&Scenario) -> Vec<Action>,
    configs: &[PlannerConfig],
) -> Vec<Vec<RobotState>> {
    let mut paths = Vec::new();
    let mut most = (0, String::new());
    let clock = std::time::Instant::now();
    for scene in scenes {
        let fresh = Env::new(scene, env_config(robot)).unwrap();
        let mut env = fresh.clone();
        let mut actions = prefix(scene);
        for (i, &action) in actions.iter().enumerate() {
            let outcome = env.step(action).unwrap();
            assert_eq!(outcome.invalid, None, "{}: prefix step {i}", scene.name);
        }
        // A prefix may end at the target already: then there is nothing left to plan.
        if env.status() != Status::Success {
            // The first search that finds a plan proves the scene solvable.
            let mut effort = Vec::new();
            let solved = configs.iter().find_map(|config| {
                let found = plan(&env, config);
                effort.push((found.outcome.clone(), found.expansions));
                match found.outcome {
                    PlanOutcome::Solved { actions, .. } => Some(actions),
                    _ => None,
                }
            });
            match solved {
                Some(rest) => actions.extend(rest),
                None => panic!("{}: no search finds a plan: {effort:?}", scene.name),
            }
            let expansions = effort.iter().map(|(_, e)| e).sum();
            if expansions >= most.0 {
                most = (expansions, scene.name.clone());
            }
        }
        let mut replay = fresh;
        let mut path = vec![*replay.state()];
        for &action in &actions {
            let outcome = replay.step(action).unwrap();
            assert_eq!(outcome.invalid, None, "{}", scene.name);
            path.push(*replay.state());
        }
        assert_eq!(replay.status(), Status::Success, "{}", scene.name);
        paths.push(path);
    }
    println!(
        "{} scenes in {:.1} s; most expansions {} ({})",
        scenes.len(),
        clock.elapsed().as_secs_f32(),
        most.0,
        most.1
    );
    paths
}

/// The weighted search's settings for the proofs below.
pub fn weighted(weight: f32) -> PlannerConfig {
    PlannerConfig {
        max_expansions: 20_000,
        heuristic_weight: weight,
        ..PlannerConfig::default()
    }
}

/// Breadth-first search over full states (exact position, yaw, clearance, track) with the
/// simulator's transition check, on the episode's action lattice, the step limit and the give-up
/// rule (the episode's, which counts from where it started): the reference the planner must
/// match. Exponential; only for tiny, restricted instances. States from which
/// even straight-line travel at the longest step cannot reach the target within `depth` steps
/// are cut, which never cuts a plan of at most `depth` steps.
pub fn brute_force(env: &Env, config: &PlannerConfig, depth: usize) -> Option<usize> {
    brute_force_within(env, config, depth, env.give_up_distance_m())
}

/// [`brute_force`] with the give-up distance `give_up_m` in place of the episode's.
pub fn brute_force_within(
    env: &Env,
    config: &PlannerConfig,
    depth: usize,
    give_up_m: f32,
) -> Option<usize> {
    let actions: Vec<Action> = (0..COUNT)
        .filter(|&i| config.allowed[i])
        .filter_map(Action::from_index)
        .filter(|a| *a != Action::IDLE)
        .collect();
    // The exact position, not rounded: the same lattice point reached in another order may
    // differ in the last bits, and where a step or the success radius is decided within them,
    // a rounded key would keep only the first variant met.
    let key = |s: &RobotState| {
        (
            s.position.x.to_bits(),
            s.position.y.to_bits(),
            s.yaw_steps,
            s.clearance_steps,
            s.track_steps,
        )
    };
    let start = *env.state();
    let radius_m = env.config().success_radius_m;
    let longest_m = env.lattice().move_step_m * std::f32::consts::SQRT_2;
    let mut seen = HashMap::from([(key(&start), 0usize)]);
    let mut queue = VecDeque::from([(start, 0usize)]);
    while let Some((state, steps)) = queue.pop_front() {
        for &action in &actions {
            let next = state.after(action);
            let distance_m = (env.target() - next.position).norm();
            if distance_m > give_up_m || env.check_transition(&state, &next).is_err() {
                continue;
            }
            if distance_m <= radius_m {
                return Some(steps + 1);
            }
            let left = depth.saturating_sub(steps + 1) as f32;
            if steps + 1 >= env.config().max_steps as usize
                || distance_m - radius_m > left * longest_m + 1e-4
            {
                continue;
            }
            if seen.insert(key(&next), steps + 1).is_none() {
                queue.push_back((next, steps + 1));
            }
        }
    }
    None
}

/// Length of a shortest plan (the planner's own replay check has run on it).
pub fn shortest(env: &Env, config: &PlannerConfig) -> usize {
    match plan(env, config).outcome {
        PlanOutcome::Solved {
            actions,
            shortest: true,
        } => actions.len(),
        other => panic!("expected a shortest plan, got {other:?}"),
    }
}
