//! Composed scenes (`wheelleg generate --kind composed`): every variant is drawn, each fence in
//! them needs its behaviour (with the legs frozen no pose gets across it, whatever the clutter
//! does), and a scene of every variant is solvable (a plan replayed to success).
//!
//! Run in release mode: about a minute.

use nalgebra::Point2;
use rand::SeedableRng;
use std::collections::BTreeMap;
use wheelleg_runtime::action::{Action, Step};
use wheelleg_runtime::robot::WHEELLEG;
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::generate::{
    generate_many, Behaviour, ComposedEnding, ComposedVariant, SceneKind, COMPOSED_PAIRS,
};
use wheelleg_sim::obstacle::GRID_CELL_M;
use wheelleg_sim::planner::{plan, PlanOutcome};
use wheelleg_sim::robot::SimulatedRobot;
use wheelleg_sim::scenario::Scenario;

mod common;
use common::{fence_blocks, lattice_legs, prove_solvable, weighted, LegFilter};

/// 400 held-out-style composed scenes of one seed.
fn sample() -> Vec<Scenario> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(31);
    generate_many(
        wheelleg_sim::generate::SceneRobot::shipped(),
        SceneKind::Composed,
        &mut rng,
        400,
    )
}

/// The first scene of each variant in `scenes`, by variant name.
fn first_of_each_variant(scenes: &[Scenario]) -> BTreeMap<String, (ComposedVariant, Scenario)> {
    let mut firsts = BTreeMap::new();
    for scene in scenes {
        let variant = ComposedVariant::of_name(&scene.name).expect("a composed name");
        firsts
            .entry(variant.name())
            .or_insert_with(|| (variant, scene.clone()));
    }
    firsts
}

/// The rows of obstacles that span the arena (a fence row holds at least 7 obstacles at one x;
/// clutter adds at most 5 anywhere), grouped into fences of adjacent rows, nearest first: each
/// fence as a scene of its own obstacles only.
fn fences_of(scene: &Scenario) -> Vec<Scenario> {
    let mut rows: BTreeMap<i32, usize> = BTreeMap::new();
    for o in &scene.obstacles {
        *rows
            .entry((o.centre.x / GRID_CELL_M).floor() as i32)
            .or_default() += 1;
    }
    let fence_rows: Vec<i32> = rows
        .into_iter()
        .filter(|&(_, n)| n >= 6)
        .map(|(row, _)| row)
        .collect();
    let mut fences: Vec<Vec<i32>> = Vec::new();
    for row in fence_rows {
        match fences.last_mut() {
            Some(f) if f.last() == Some(&(row - 1)) => f.push(row),
            _ => fences.push(vec![row]),
        }
    }
    fences
        .into_iter()
        .map(|rows| Scenario {
            obstacles: scene
                .obstacles
                .iter()
                .filter(|o| rows.contains(&((o.centre.x / GRID_CELL_M).floor() as i32)))
                .copied()
                .collect(),
            ..scene.clone()
        })
        .collect()
}

/// Leg configurations a fence of `behaviour` blocks (frozen in the dimension the behaviour
/// moves) and lets through (that dimension at the behaviour's end).
fn leg_filters(behaviour: Behaviour) -> (LegFilter, LegFilter) {
    match behaviour {
        Behaviour::LiftOver => (|c, _| c == 0, |c, _| c >= 2),
        Behaviour::SpreadOver => (|_, t| t == 0, |_, t| t == 10),
        Behaviour::Squeeze => (|_, t| t == 0, |_, t| t == -10),
        other => panic!("{other:?} builds no fence"),
    }
}

#[test]
fn every_variant_is_drawn_and_named() {
    let scenes = sample();
    let firsts = first_of_each_variant(&scenes);
    let mut expected = Vec::new();
    for ending in [ComposedEnding::Beyond, ComposedEnding::InPassage] {
        for fences in [
            Behaviour::LiftOver,
            Behaviour::SpreadOver,
            Behaviour::Squeeze,
        ]
        .map(|b| vec![b])
        .into_iter()
        .chain(COMPOSED_PAIRS.map(|(a, b)| vec![a, b]))
        {
            expected.push(ComposedVariant { fences, ending }.name());
        }
    }
    expected.sort();
    assert_eq!(firsts.keys().cloned().collect::<Vec<_>>(), expected);
    for scene in &scenes {
        let variant = ComposedVariant::of_name(&scene.name).unwrap();
        let fences = fences_of(scene);
        assert_eq!(fences.len(), variant.fences.len(), "{}", scene.name);
        let fence_obstacles: usize = fences.iter().map(|f| f.obstacles.len()).sum();
        let clutter = scene.obstacles.len() - fence_obstacles;
        assert!((1..=5).contains(&clutter), "{}: {clutter}", scene.name);
        let last_x = fences
            .last()
            .unwrap()
            .obstacles
            .iter()
            .map(|o| o.centre.x)
            .fold(f32::NAN, f32::max);
        match variant.ending {
            ComposedEnding::Beyond => assert!(scene.target.x > last_x, "{}", scene.name),
            ComposedEnding::InPassage => assert!(scene.target.x <= last_x, "{}", scene.name),
        }
    }
    // Clutter: 2 to 5 asked for, fewer only where the lane leaves no room.
    let with_two_or_more = scenes
        .iter()
        .filter(|s| {
            let fenced: usize = fences_of(s).iter().map(|f| f.obstacles.len()).sum();
            s.obstacles.len() - fenced >= 2
        })
        .count();
    assert!(with_two_or_more >= 380, "{with_two_or_more} of 400");
}

#[test]
fn each_fence_of_every_variant_needs_its_behaviour() {
    // With the legs frozen in the behaviour's dimension, no pose near the fence's first row or
    // its middle is free at any lateral position across the arena and any yaw: no way across,
    // and clutter (only more obstacles, never in a fence row) cannot open one. With the legs
    // at the behaviour's end the fence lets the robot through. Each fence kind in each place
    // it takes, once: the proof is per fence, the same for every variant.
    let mut proven = std::collections::BTreeSet::new();
    for (name, (variant, scene)) in first_of_each_variant(&sample()) {
        let fences = variant.fences.iter().zip(fences_of(&scene)).enumerate();
        for (position, (behaviour, fence)) in fences {
            if !proven.insert((behaviour.name(), position)) {
                continue;
            }
            let (frozen, with_behaviour) = leg_filters(*behaviour);
            assert!(
                fence_blocks(
                    &fence,
                    &WHEELLEG,
                    &lattice_legs(&SimulatedRobot::SHIPPED, frozen)
                ),
                "{name}: the {} fence must block frozen legs",
                behaviour.name()
            );
            assert!(
                !fence_blocks(
                    &fence,
                    &WHEELLEG,
                    &lattice_legs(&SimulatedRobot::SHIPPED, with_behaviour)
                ),
                "{name}: the {} fence must let the behaviour through",
                behaviour.name()
            );
        }
    }
    // Lift, spread and squeeze first; lift and squeeze second (no pair ends with a slab).
    assert_eq!(proven.len(), 5, "{proven:?}");
}

/// In place: turn the short way to face along x (towards or away from the target), then move
/// the legs from `from` to `to` (clearance steps, track steps), both at once where they can:
/// low and wide is reachable only in order, so lowering comes first and rising last.
fn line_up(yaw_steps: i32, from: (i32, i32), to: (i32, i32)) -> Vec<Action> {
    let yaw = yaw_steps.rem_euclid(72);
    let (turn, turns) = match yaw {
        0..=18 => (Step::Minus, yaw),
        19..=35 => (Step::Plus, 36 - yaw),
        36..=53 => (Step::Minus, yaw - 36),
        _ => (Step::Plus, 72 - yaw),
    };
    let mut actions = vec![
        Action {
            yaw: turn,
            ..Action::IDLE
        };
        turns as usize
    ];
    let towards = |d: i32| if d > 0 { Step::Plus } else { Step::Minus };
    let (dc, dt) = (to.0 - from.0, to.1 - from.1);
    let steps = dc.abs().max(dt.abs());
    // Lowering: both dimensions from the first step on; rising: both up to the last step.
    let moves = |k: i32, d: i32| {
        if dc < 0 {
            k < d.abs()
        } else {
            k >= steps - d.abs()
        }
    };
    for k in 0..steps {
        actions.push(Action {
            clearance: if moves(k, dc) {
                towards(dc)
            } else {
                Step::Zero
            },
            track: if moves(k, dt) {
                towards(dt)
            } else {
                Step::Zero
            },
            ..Action::IDLE
        });
    }
    actions
}

/// Where the robot takes a fence: lined up on its passage's centre line (the opening the
/// generator drew is the middle of the first row: the middle bar, the middle slab, the gap
/// between the two middle blocks), half a metre before its first row (the middle of the gap
/// between two fences), and the x as far past its last row.
fn entry_and_exit_x(fence: &Scenario) -> (Point2<f32>, f32) {
    let first_x = fence
        .obstacles
        .iter()
        .map(|o| o.centre.x)
        .fold(f32::NAN, f32::min);
    let last_x = fence
        .obstacles
        .iter()
        .map(|o| o.centre.x)
        .fold(f32::NAN, f32::max);
    let mut ys: Vec<f32> = fence
        .obstacles
        .iter()
        .filter(|o| o.centre.x == first_x)
        .map(|o| o.centre.y)
        .collect();
    ys.sort_by(f32::total_cmp);
    let middle = 0.5 * (ys[(ys.len() - 1) / 2] + ys[ys.len() / 2]);
    (Point2::new(first_x - 0.5, middle), last_x + 0.5)
}

#[test]
fn a_scene_of_every_variant_is_solvable() {
    // The search over every action runs out of budget in front of squeeze and spread fences
    // (`scenarios.rs` says why), so the proof takes a fence at a time, as a driver would: the
    // planner's weighted search, legs frozen (a node is one pose), to half a
    // metre before the fence on its passage's centre line; there, in place, turn to face along
    // x and move the legs to the fence's passing pose (`generate::passing_legs`); the search
    // again, legs frozen in that pose, through the fence to half a metre past it (the next
    // fence's entry), and so on; after the last fence the search in its passing pose to the
    // target. The whole sequence is replayed to success in a fresh episode, which holds it to
    // the episode's 100 steps.
    let frozen = weighted(3.0).restricted(|a| a.clearance == Step::Zero && a.track == Step::Zero);
    // A plan from where `env` stands in `scene` to `target`, in a copy of the scene with that
    // target and an arena within the scene's (the box around start and target, grown by the
    // margin), so that the plan stays in bounds in the whole episode too.
    let plan_to = |scene: &Scenario, env: &Env, target: Point2<f32>| {
        let part = Scenario {
            start: *env.state(),
            target,
            ..scene.clone()
        };
        let margin_m = EnvConfig::default().arena_margin_m;
        let bounds = |a: Point2<f32>, b: Point2<f32>| {
            (a.x.min(b.x), a.x.max(b.x), a.y.min(b.y), a.y.max(b.y))
        };
        let whole = bounds(scene.start.position, scene.target);
        let inner = bounds(part.start.position, target);
        let room_m = [
            inner.0 - whole.0,
            whole.1 - inner.1,
            inner.2 - whole.2,
            whole.3 - inner.3,
        ]
        .into_iter()
        .fold(margin_m, |m, side_m| m.min(side_m + margin_m));
        let config = EnvConfig {
            arena_margin_m: room_m.max(0.0),
            ..EnvConfig::default()
        };
        let part_env = Env::new(&part, config).unwrap();
        match plan(&part_env, &frozen).outcome {
            PlanOutcome::Solved { actions, .. } => actions,
            other => panic!("{} to {target:?}: {other:?}", part.name),
        }
    };
    let all_but_last = |scene: &Scenario| {
        let variant = ComposedVariant::of_name(&scene.name).unwrap();
        let mut env = Env::new(scene, EnvConfig::default()).unwrap();
        let mut actions = Vec::new();
        let take = |env: &mut Env, more: Vec<Action>, actions: &mut Vec<Action>| {
            // A way through may end at a target just past the fence: the episode is over.
            for a in more {
                if env.status().is_done() {
                    break;
                }
                let outcome = env.step(a).unwrap();
                assert_eq!(outcome.invalid, None, "{}", scene.name);
                actions.push(a);
            }
        };
        let fences = fences_of(scene);
        let mut legs = (0, 0);
        for (i, (behaviour, fence)) in variant.fences.iter().zip(&fences).enumerate() {
            let (entry, exit_x) = entry_and_exit_x(fence);
            let to_entry = plan_to(scene, &env, entry);
            take(&mut env, to_entry, &mut actions);
            let passing = wheelleg_sim::generate::SceneRobot::shipped().passing_legs(*behaviour);
            let yaw_steps = env.state().yaw_steps;
            take(&mut env, line_up(yaw_steps, legs, passing), &mut actions);
            legs = passing;
            let exit = Point2::new(exit_x, entry.y);
            let last = i + 1 == fences.len();
            // The last fence's passage holds the target, or the target lies right at its exit:
            // the final search takes the robot there.
            if !(last
                && (variant.ending == ComposedEnding::InPassage
                    || (scene.target - exit).norm() < 0.1))
            {
                // Through, legs frozen in the passing pose, to as far past the fence as its
                // entry was before it.
                let through = plan_to(scene, &env, exit);
                take(&mut env, through, &mut actions);
            }
        }
        actions
    };
    let firsts = first_of_each_variant(&sample());
    let scenes: Vec<Scenario> = firsts.values().map(|(_, s)| s.clone()).collect();
    let paths = prove_solvable(&scenes, &SimulatedRobot::SHIPPED, all_but_last, &[frozen]);
    for ((variant, scene), path) in firsts.values().zip(paths) {
        for behaviour in &variant.fences {
            let passing = wheelleg_sim::generate::SceneRobot::shipped().passing_legs(*behaviour);
            assert!(
                path.iter()
                    .any(|s| (s.clearance_steps, s.track_steps) == passing),
                "{}: never in the {} pose",
                scene.name,
                behaviour.name()
            );
        }
    }
}
