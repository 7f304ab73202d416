//! The world's step check, made fast (cached start poses, a table of the legs' motion, cheap
//! lower bounds on clearance before parry's queries), decides every step exactly as the plain
//! rule it replaced: a reference implementation of `Env::check_transition` kept here, written
//! only with public queries and without any of the shortcuts, against the env on many random
//! transitions in complex and lift scenes, through `check_transition` and through `step`.

use rand::{Rng, SeedableRng};
use wheelleg_runtime::action::{Action, COUNT};
use wheelleg_sim::collision::RobotParts;
use wheelleg_sim::env::{Env, EnvConfig, InvalidAction, GRAZE_TOLERANCE_M};
use wheelleg_sim::generate::{generate_many, SceneKind};
use wheelleg_sim::state::RobotState;

/// What each stage of the reference decided, for the report.
#[derive(Default, Debug)]
struct Stages {
    far: u32,
    end_collides: u32,
    sweep_clear: u32,
    proven: u32,
    refused_on_the_way: u32,
    other: u32,
}

/// `Env::check_transition` as first written (commit 0cd7e97): the arena, the legs' IK, the box
/// test around both ends, the end pose's exact test, the sweep box test, then the clearance
/// bisection with parry's queries at every pose.
fn reference(
    env: &Env,
    from: &RobotState,
    to: &RobotState,
    stages: &mut Stages,
) -> Result<(), InvalidAction> {
    let geometry = env.geometry();
    // The arena comes first in `Env`; the callers skip what it refuses as out of bounds.
    let p = to.position;
    let legs = to.leg_config(geometry);
    geometry.leg_ik(legs).map_err(InvalidAction::Impossible)?;
    let reach_m = reach_m(env);
    if !env.obstacles().any_within_span(from.position, p, reach_m) {
        stages.far += 1;
        return Ok(());
    }
    let end =
        RobotParts::new(geometry, p, to.yaw_rad(), legs).map_err(InvalidAction::Impossible)?;
    if env.obstacles().may_touch(&end.aabb()) && env.obstacles().collides(&end) {
        stages.end_collides += 1;
        return Err(InvalidAction::Collision);
    }
    if from == to {
        stages.other += 1;
        return Ok(());
    }
    let bound_m = reference_motion_bound_m(env, from, to).map_err(InvalidAction::Impossible)?;
    assert_eq!(
        bound_m.to_bits(),
        env.motion_bound_m(from, to).expect("bound").to_bits(),
        "{from:?} -> {to:?}"
    );
    let start = env
        .pose_between(from, to, 0.0)
        .map_err(InvalidAction::Impossible)?;
    if !env.obstacles().sweep_may_touch(&start, &end, 0.5 * bound_m) {
        stages.sweep_clear += 1;
        return Ok(());
    }
    let enough = |travel_m: f32| 0.5 * travel_m * (1.0 + 1.0e-3) + GRAZE_TOLERANCE_M;
    let start_m = env
        .obstacles()
        .clearance_m(&start, enough(bound_m))
        .unwrap_or(0.0);
    let Some(end_m) = env.obstacles().clearance_m(&end, enough(bound_m)) else {
        stages.refused_on_the_way += 1;
        return Err(InvalidAction::Collision);
    };
    let mut open = vec![(0.0f32, start_m, 1.0f32, end_m)];
    while let Some((a, a_m, b, b_m)) = open.pop() {
        let travel_m = bound_m * (b - a);
        if a_m + b_m > travel_m {
            continue;
        }
        if travel_m < GRAZE_TOLERANCE_M {
            stages.refused_on_the_way += 1;
            return Err(InvalidAction::Collision);
        }
        let mid = 0.5 * (a + b);
        let parts = env
            .pose_between(from, to, mid)
            .map_err(InvalidAction::Impossible)?;
        let Some(mid_m) = env.obstacles().clearance_m(&parts, enough(travel_m)) else {
            stages.refused_on_the_way += 1;
            return Err(InvalidAction::Collision);
        };
        open.push((mid, mid_m, b, b_m));
        open.push((a, a_m, mid, mid_m));
    }
    stages.proven += 1;
    Ok(())
}

/// The horizontal reach `Env` uses for its first box test (a copy of its private
/// `horizontal_reach_m`).
fn reach_m(env: &Env) -> f32 {
    let g = env.geometry();
    let body = (0.5 * g.body_length_m).hypot(0.5 * g.body_width_m);
    let wheel =
        (g.hip_x_m + g.wheel_radius_m).hypot(0.5 * g.track_range_m[1] + 0.5 * g.wheel_width_m);
    let knee = g.hip_x_m.hypot(g.hip_y_m + g.thigh_m + g.link_radius_m);
    body.max(wheel).max(knee) + 0.01
}

/// `Env::motion_bound_m` as first written: the legs' path measured in 16 pieces every time.
fn reference_motion_bound_m(
    env: &Env,
    from: &RobotState,
    to: &RobotState,
) -> Result<f32, wheelleg_runtime::leg::IkError> {
    let geometry = env.geometry();
    let travel_m = (to.position - from.position).norm();
    let yaw_delta = (to.yaw_steps - from.yaw_steps + 1).rem_euclid(from.yaw_steps_per_turn()) - 1;
    let turn_m = reach_m(env)
        * (yaw_delta as f32 * from.lattice.yaw_step_deg)
            .to_radians()
            .abs();
    let (legs0, legs1) = (from.leg_config(geometry), to.leg_config(geometry));
    let leg_m = if legs0 == legs1 {
        0.0
    } else {
        let leg = wheelleg_runtime::robot::LegId::FrontLeft;
        let mut previous: Option<[nalgebra::Point3<f32>; 3]> = None;
        let mut longest_piece_m = 0.0f32;
        for piece in 0..=16u32 {
            let t = piece as f32 / 16.0;
            let legs = wheelleg_runtime::leg::LegConfig {
                clearance_m: legs0.clearance_m + t * (legs1.clearance_m - legs0.clearance_m),
                track_m: legs0.track_m + t * (legs1.track_m - legs0.track_m),
            };
            let points = geometry.leg_points(leg, geometry.leg_ik(legs)?);
            let lift = nalgebra::Vector3::z() * geometry.body_centre_height_m(legs.clearance_m);
            let now = [points.hip + lift, points.knee + lift, points.wheel + lift];
            if let Some(before) = previous {
                for (a, b) in before.iter().zip(&now) {
                    longest_piece_m = longest_piece_m.max((b - a).norm());
                }
            }
            previous = Some(now);
        }
        1.5 * 16.0 * longest_piece_m
    };
    Ok(travel_m + turn_m + leg_m)
}

/// Walks random episodes of `kind` and holds every step's decision, and a spread of other
/// actions' decisions from each visited state, to the reference.
fn compare(kind: &str, seed: u64, scenes: usize, tries_per_state: usize) -> Stages {
    let kind = SceneKind::from_name(kind).expect("known kind");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut stages = Stages::default();
    let mut compared = 0u32;
    for scenario in generate_many(
        wheelleg_sim::generate::SceneRobot::shipped(),
        kind,
        &mut rng,
        scenes,
    ) {
        let mut env = Env::new(&scenario, EnvConfig::default()).expect("valid scene");
        while !env.status().is_done() {
            let from = *env.state();
            for _ in 0..tries_per_state {
                let to =
                    from.after(Action::from_index(rng.random_range(0..COUNT)).expect("in range"));
                let got = env.check_transition(&from, &to);
                if got == Err(InvalidAction::OutOfBounds) {
                    continue;
                }
                assert_eq!(
                    got,
                    reference(&env, &from, &to, &mut stages),
                    "{from:?} -> {to:?}"
                );
                compared += 1;
            }
            let action = Action::from_index(rng.random_range(0..COUNT)).expect("in range");
            let to = from.after(action);
            let outcome = env.step(action).expect("running");
            if outcome.invalid != Some(InvalidAction::OutOfBounds) {
                assert_eq!(
                    outcome.invalid,
                    reference(&env, &from, &to, &mut stages).err(),
                    "step {from:?} -> {to:?}"
                );
                compared += 1;
            }
        }
    }
    eprintln!("{kind:?}: {compared} compared, {stages:?}");
    assert!(compared > 10_000, "only {compared} compared");
    stages
}

#[test]
fn complex_scene_steps_are_decided_as_by_the_plain_rule() {
    let stages = compare("complex", 11, 48, 8);
    assert!(
        stages.proven > 100 && stages.refused_on_the_way > 10,
        "{stages:?}"
    );
}

#[test]
fn lift_scene_steps_are_decided_as_by_the_plain_rule() {
    let stages = compare("lift", 12, 48, 8);
    assert!(
        stages.proven > 100 && stages.refused_on_the_way > 10,
        "{stages:?}"
    );
}

/// The cheap bound the proof tries first is a lower bound on parry's clearance (less the
/// slack), and at most 0 for a pose that touches, at poses along random steps near obstacles.
#[test]
fn the_cheap_clearance_bound_is_below_parrys() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
    let (mut checked, mut touching, mut ratio_sum) = (0u32, 0u32, 0.0f64);
    for name in ["complex", "lift"] {
        let kind = SceneKind::from_name(name).expect("known kind");
        for scenario in generate_many(
            wheelleg_sim::generate::SceneRobot::shipped(),
            kind,
            &mut rng,
            40,
        ) {
            let env = Env::new(&scenario, EnvConfig::default()).expect("valid scene");
            let mut from = *env.state();
            for _ in 0..60 {
                let to =
                    from.after(Action::from_index(rng.random_range(0..COUNT)).expect("in range"));
                let t = rng.random_range(0.0..1.0);
                if let Ok(parts) = env.pose_between(&from, &to, t) {
                    for up_to_m in [0.002, 0.02, 0.1, 0.5] {
                        let bound_m = env.obstacles().clearance_lower_bound_m(&parts, up_to_m);
                        match env.obstacles().clearance_m(&parts, up_to_m) {
                            Some(exact_m) => {
                                assert!(
                                    bound_m <= exact_m,
                                    "{from:?} -> {to:?} at {t}: bound {bound_m} > {exact_m}"
                                );
                                if up_to_m == 0.5 && exact_m > 0.0 {
                                    ratio_sum += f64::from(bound_m.max(0.0) / exact_m);
                                }
                            }
                            None => {
                                touching += 1;
                                assert!(bound_m <= 0.0, "touching, bound {bound_m}");
                            }
                        }
                        checked += 1;
                    }
                }
                if env.check_transition(&from, &to).is_ok() {
                    from = to;
                }
            }
        }
    }
    eprintln!(
        "{checked} checked, {touching} touching, mean bound/exact {}",
        ratio_sum / f64::from(checked / 4)
    );
    assert!(touching > 50, "only {touching} touching poses tried");
}
