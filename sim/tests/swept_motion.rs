//! A step is checked along its whole way, not only at its ends: the proof of
//! `Env::check_transition` against fine sampling of the path, and the motion bound it rests on
//! against measured paths.

use nalgebra::{Point2, Point3, Vector3};
use rand::{Rng, SeedableRng};
use wheelleg_runtime::action::{Action, COUNT};
use wheelleg_runtime::robot::WHEELLEG;
use wheelleg_sim::collision::{Part, RobotParts};
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::obstacle::{Obstacle, ObstacleKind, ObstacleYaw};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;

fn env_with(obstacles: Vec<Obstacle>) -> Env {
    let scenario = Scenario {
        name: "swept".into(),
        start: RobotState::new(
            Point2::new(-0.975, 0.025),
            0,
            &wheelleg_runtime::action::ActionLattice::PAPER,
        ),
        target: Point2::new(0.975, 0.025),
        obstacles,
    };
    Env::new(&scenario, EnvConfig::default()).expect("valid scene")
}

/// Points whose paths bound every part's motion: body corners, link ends, wheel centres and
/// rims.
fn key_points(parts: &RobotParts) -> Vec<Point3<f32>> {
    let mut points = Vec::new();
    for part in parts.parts() {
        match part {
            Part::Body { pose, shape } => {
                let h = shape.half_extents;
                for sx in [-1.0, 1.0] {
                    for sy in [-1.0, 1.0] {
                        for sz in [-1.0, 1.0] {
                            points.push(pose * Point3::new(sx * h.x, sy * h.y, sz * h.z));
                        }
                    }
                }
            }
            Part::Link(capsule) => {
                points.push(capsule.segment.a);
                points.push(capsule.segment.b);
            }
            Part::Wheel { pose, shape } => {
                for (x, y, z) in [(0.0, 0.0, 0.0), (1.0, 1.0, 0.0), (-1.0, -1.0, 0.0)] {
                    let offset = Vector3::new(x * shape.radius, y * shape.half_height, z);
                    points.push(pose * Point3::from(offset));
                }
            }
        }
    }
    points
}

#[test]
fn the_motion_bound_covers_every_step_from_every_lattice_leg_pose() {
    let env = env_with(Vec::new());
    const PIECES: u32 = 200;
    let mut checked = 0;
    let mut tightest = 0.0f32;
    let mut tightest_legs = 0.0f32;
    let mut largest_bound_m = 0.0f32;
    for clearance_steps in -5..=7 {
        for track_steps in -11..=11 {
            let mut from = RobotState::new(
                Point2::new(0.025, 0.025),
                3,
                &wheelleg_runtime::action::ActionLattice::PAPER,
            );
            from.clearance_steps = clearance_steps;
            from.track_steps = track_steps;
            if WHEELLEG.leg_ik(from.leg_config(&WHEELLEG)).is_err() {
                continue;
            }
            for index in 0..COUNT {
                let to = from.after(Action::from_index(index).expect("in range"));
                let Ok(bound_m) = env.motion_bound_m(&from, &to) else {
                    continue;
                };
                let mut path_m = 0.0f32;
                let mut previous: Option<Vec<Point3<f32>>> = None;
                let mut reachable = true;
                for piece in 0..=PIECES {
                    let Ok(parts) = env.pose_between(&from, &to, piece as f32 / PIECES as f32)
                    else {
                        reachable = false;
                        break;
                    };
                    let now = key_points(&parts);
                    if let Some(before) = &previous {
                        let longest = before
                            .iter()
                            .zip(&now)
                            .map(|(a, b)| (b - a).norm())
                            .fold(0.0, f32::max);
                        path_m = path_m.max(longest * PIECES as f32);
                    }
                    previous = Some(now);
                }
                if !reachable {
                    continue;
                }
                // Positions are f32: about 0.1 um of rounding per point, times PIECES in the
                // measured speed.
                assert!(
                    path_m <= bound_m + 5.0e-5,
                    "{from:?} -> {to:?}: a point moves at up to {path_m} m per step, bound {bound_m}"
                );
                tightest = tightest.max(path_m / bound_m);
                largest_bound_m = largest_bound_m.max(bound_m);
                if from.position == to.position && from.yaw_steps == to.yaw_steps {
                    tightest_legs = tightest_legs.max(path_m / bound_m);
                }
                checked += 1;
            }
        }
    }
    eprintln!(
        "checked {checked} steps, tightest measured/bound {tightest}, legs only \
         {tightest_legs}; largest bound {largest_bound_m} m"
    );
    // The planner looks this far around a step for obstacles (its SWEEP_GROW_M, 0.1 m, is half
    // a bound); a larger bound would only cost it speed, but says the motion is not a step's.
    assert!(largest_bound_m < 0.2, "largest bound {largest_bound_m} m");
    assert!(checked > 10_000, "only {checked} steps checked");
    // The bound is not slack for nothing: somewhere it is close to the truth.
    assert!(tightest > 0.7, "tightest ratio {tightest}");
}

/// Lifted over a lengthwise bar, the legs on either side: the tightest place of the world.
fn states_around_a_bar(rng: &mut impl Rng, count: usize, env: &Env) -> Vec<RobotState> {
    let mut states = Vec::new();
    while states.len() < count {
        let mut state = RobotState::new(
            Point2::new(
                0.025 + 0.05 * rng.random_range(0..12) as f32,
                0.025 + 0.05 * rng.random_range(0..4) as f32,
            ),
            rng.random_range(-3..=3),
            &wheelleg_runtime::action::ActionLattice::PAPER,
        );
        state.clearance_steps = rng.random_range(1..=4);
        state.track_steps = rng.random_range(-4..=3);
        // Valid places only: reachable, inside, touching nothing (a step to itself).
        if env.check_transition(&state, &state).is_ok() {
            states.push(state);
        }
    }
    states
}

#[test]
fn accepted_steps_touch_nothing_on_the_way_and_cut_corners_are_refused() {
    let env = env_with(vec![
        Obstacle::new(ObstacleKind::Bar, 0.375, 0.125, ObstacleYaw::default()),
        Obstacle::new(ObstacleKind::Block, 0.625, -0.125, ObstacleYaw::default()),
    ]);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut accepted = 0;
    let mut ends_clear_way_not = 0;
    for from in states_around_a_bar(&mut rng, 60, &env) {
        for index in 0..COUNT {
            let to = from.after(Action::from_index(index).expect("in range"));
            let proven = env.check_transition(&from, &to);
            // One pose per millimetre of motion or finer.
            let sampled = env.check_swept(&from, &to, 150, 0.0);
            if proven.is_ok() {
                accepted += 1;
                assert!(
                    sampled.is_ok(),
                    "{from:?} -> {to:?} accepted, but touches at {sampled:?}"
                );
            } else if sampled.is_err() && env.check_swept(&from, &to, 2, 0.0).is_ok() {
                // Start, half-way and end clear, contact in between: what a three-pose rule
                // let through.
                ends_clear_way_not += 1;
            }
        }
    }
    eprintln!("{accepted} accepted, {ends_clear_way_not} with clear ends refused");
    assert!(accepted > 1_000, "only {accepted} steps accepted");
    assert!(
        ends_clear_way_not > 0,
        "no step with clear ends and a contact on the way was tried"
    );
}
