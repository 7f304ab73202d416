//! The whole system: world -> driver -> runtime -> CAN -> simulated motors -> measured motion ->
//! world (`wheelleg::closed_loop` and the `wheelleg demo` binary).
//!
//! Tolerances are the loop's defaults ([`Tolerance::default`]: 2 mm, 0.2°, 0.5 mm per step
//! against the simulator's ideal step; docs/can-protocol.md, "Closed loop demo").
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing)]

mod decision_stack;
mod demo_cli;
mod mechanics;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};
use std::process::Command;
use wheelleg::closed_loop::success::{compare_success, simulate};
use wheelleg::closed_loop::{
    ClosedLoop, Driver, Fault, LoopConfig, LoopError, PlannerDriver, PolicyDriver, StepError,
    StepKind, Tolerance,
};
use wheelleg_firmware_sim::candump::{parse_log, CandumpWriter, DEFAULT_EPOCH_US};
use wheelleg_firmware_sim::rig::{true_wheel_speed_sum, StopReason};
use wheelleg_runtime::action::{Action, Step};
use wheelleg_runtime::can::node_map::{Axis, Joint};
use wheelleg_runtime::guard::DEFAULT_MARGIN_M;
use wheelleg_runtime::robot::{LegId, WHEELLEG};
use wheelleg_sim::env::{Env, InvalidAction, Observation, Status};
use wheelleg_sim::generate::{generate, Behaviour, SceneKind};
use wheelleg_sim::height_map::MapGrid;
use wheelleg_sim::planner::PlannerConfig;
use wheelleg_sim::scenario::Scenario;
use wheelleg_stack::lookahead::LookaheadConfig;
use wheelleg_stack::{GuardLayer, Preset, StackConfig};
use wheelleg_trainer::network_f32::{Architecture, NetworkF32};
use wheelleg_trainer::quantize::{quantize, Calibration, RangeMethod};

/// Enough for the complex and lift-over scenes used here (they plan in under a thousand
/// expansions); a scene needing more is skipped rather than slowing the suite (proving a
/// complex scene unsolvable can take minutes).
fn planner() -> PlannerConfig {
    PlannerConfig {
        max_expansions: 2_000,
        ..PlannerConfig::default()
    }
}

/// `count` scenes of `kind` the planner solves, drawn from `seed`.
fn solvable_scenes(kind: SceneKind, seed: u64, count: usize) -> Vec<Scenario> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut scenes = Vec::new();
    for i in 0..10 * count {
        let scene = generate(
            wheelleg_sim::generate::SceneRobot::shipped(),
            kind,
            &mut rng,
            format!("{}-{i}", kind.name()),
        );
        let env = Env::new(&scene, LoopConfig::default().env).unwrap();
        if PlannerDriver::new(&env, &planner()).is_ok() {
            scenes.push(scene);
        }
        if scenes.len() == count {
            return scenes;
        }
    }
    panic!("fewer than {count} solvable {} scenes", kind.name());
}

fn assert_within(error: StepError, what: &str) {
    assert!(
        error.within(&Tolerance::default()),
        "{what}: {:.4} mm, {:.4} deg, legs {:.4} mm",
        1e3 * error.position_m,
        error.yaw_rad.to_degrees(),
        1e3 * error.legs_m
    );
}

fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("wheelleg-demo-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A random default network, quantized with observations of generated scenes.
fn random_policy_bytes(seed: u64) -> Vec<u8> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let network = NetworkF32::random(&Architecture::default_policy(), &mut rng);
    let observations: Vec<Observation> = (0..16)
        .map(|i| {
            generate(
                wheelleg_sim::generate::SceneRobot::shipped(),
                SceneKind::Complex,
                &mut rng,
                format!("calibration-{i}"),
            )
        })
        .map(|s| {
            let mut o = Observation::default();
            Env::new(&s, LoopConfig::default().env)
                .unwrap()
                .observe(&mut o);
            o
        })
        .collect();
    let calibration = Calibration::from_observations(
        &network,
        observations
            .iter()
            .map(|o| (o.height_map.as_slice(), o.state.as_slice())),
    );
    quantize(&network, &calibration, RangeMethod::MinMax)
        .unwrap()
        .to_bytes()
        .unwrap()
}
