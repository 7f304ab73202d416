//! The start-stage curriculum in the trainer: the stage advances, is logged, survives a resume
//! exactly, and episodes from staged starts are not stored as trajectories.
//!
//! Run in release: `cargo test --release -p wheelleg-trainer --test start_stage`.

use std::path::PathBuf;
use wheelleg_sim::generate::Behaviour;
use wheelleg_trainer::checkpoint::Checkpoint;
use wheelleg_trainer::config::TrainConfig;
use wheelleg_trainer::runner::{
    read_metrics, train_stage, RunOptions, StageInputs, CHECKPOINT_FILE, TRAJECTORIES_FILE,
};
use wheelleg_trainer::trajectory::batch_file::TrajectoryBatch;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("wheelleg-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn staged_config(kind: &str) -> TrainConfig {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/smoke.toml");
    let mut config = TrainConfig::load(std::path::Path::new(path)).unwrap();
    config.run.scene_kind = kind.into();
    config.run.steps_per_iteration = 400;
    config.run.num_envs = 20;
    config.run.checkpoint_interval = 1;
    config.run.start_stage = 0.0;
    // Short episodes, so every iteration finishes some at each stage.
    config.run.max_episode_steps = 10;
    config.validate().unwrap();
    config
}

fn opts(out: PathBuf, resume: bool, max_iterations: Option<u64>) -> RunOptions {
    RunOptions {
        out,
        seed: 11,
        resume,
        progress: false,
        max_iterations,
        stop_at_env_steps: None,
        kind: "test".into(),
    }
}

fn inputs(behaviour: Behaviour) -> StageInputs<'static> {
    StageInputs {
        init: None,
        record: Some(behaviour),
        keep_trajectories: 100,
        ..StageInputs::default()
    }
}

#[test]
fn a_resumed_staged_run_continues_at_the_same_stage() {
    let mut config = staged_config("spread");
    // Every full window advances: the stage moves each iteration, 0 -> 0.25 -> ... -> 1.
    config.run.start_stage_success_rate = 0.0;
    config.run.start_stage_step = 0.25;
    config.run.start_stage_window = 1;
    config.run.total_env_steps = 2400;
    let whole = temp_dir("stage-whole");
    let split = temp_dir("stage-split");
    let a = train_stage(
        &config,
        &opts(whole.clone(), false, None),
        inputs(Behaviour::SpreadOver),
    )
    .unwrap();
    train_stage(
        &config,
        &opts(split.clone(), false, Some(2)),
        inputs(Behaviour::SpreadOver),
    )
    .unwrap();
    let (_, extras) = Checkpoint::load_with_extras(&split.join(CHECKPOINT_FILE)).unwrap();
    let state = extras.start_stage.expect("a staged run stores its stage");
    assert_eq!(state.stage, 0.5);
    assert_eq!(state.env_stages.len(), 20);
    let b = train_stage(
        &config,
        &opts(split.clone(), true, None),
        inputs(Behaviour::SpreadOver),
    )
    .unwrap();
    let (ca, ea) = Checkpoint::load_with_extras(&a.checkpoint).unwrap();
    let (cb, eb) = Checkpoint::load_with_extras(&b.checkpoint).unwrap();
    assert_eq!(ca.network, cb.network);
    assert_eq!(ca.envs, cb.envs);
    assert_eq!(ea, eb);
    let stages = |d: &PathBuf| {
        read_metrics(d)
            .unwrap()
            .into_iter()
            .map(|m| (m.iteration, m.start_stage, m.mean_return))
            .collect::<Vec<_>>()
    };
    assert_eq!(stages(&whole), stages(&split));
    let logged: Vec<Option<f32>> = stages(&whole).iter().map(|s| s.1).collect();
    let expected = [0.0, 0.25, 0.5, 0.75, 1.0, 1.0].map(Some);
    assert_eq!(logged, expected);
    let _ = std::fs::remove_dir_all(&whole);
    let _ = std::fs::remove_dir_all(&split);
}

#[test]
fn staged_successes_are_not_stored_and_unstaged_runs_log_no_stage() {
    // The committed straight-line policy on straight scenes (which the stages leave as they
    // are) succeeds nearly always; at stage 0, which never advances here (every episode would
    // have to succeed), nothing is stored, and without the curriculum the same run stores.
    let straight = wheelleg_trainer::checkpoint::load_policy(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/straight-secondary.ckpt"
    )))
    .unwrap();
    let mut config = staged_config("straight");
    config.run.max_episode_steps = 50;
    config.run.start_stage_success_rate = 1.0;
    config.run.total_env_steps = 1200;
    config.ppo.learning_rate = 1e-5;
    let dir = temp_dir("stage-store");
    let with_init = |behaviour| StageInputs {
        init: Some(&straight),
        ..inputs(behaviour)
    };
    train_stage(
        &config,
        &opts(dir.clone(), false, None),
        with_init(Behaviour::Straight),
    )
    .unwrap();
    let metrics = read_metrics(&dir).unwrap();
    assert!(metrics.iter().all(|m| m.start_stage == Some(0.0)));
    assert!(
        metrics.iter().any(|m| m.success_rate > 0.0),
        "successes at stage 0: {:?}",
        metrics.iter().map(|m| m.success_rate).collect::<Vec<_>>()
    );
    let stored = TrajectoryBatch::load(&dir.join(TRAJECTORIES_FILE)).unwrap();
    assert_eq!(stored.len(), 0);
    let _ = std::fs::remove_dir_all(&dir);

    // The same run without the curriculum stores its successes and logs no stage.
    config.run.start_stage = 1.0;
    let dir = temp_dir("stage-off");
    train_stage(
        &config,
        &opts(dir.clone(), false, None),
        with_init(Behaviour::Straight),
    )
    .unwrap();
    let stored = TrajectoryBatch::load(&dir.join(TRAJECTORIES_FILE)).unwrap();
    assert!(!stored.is_empty(), "full-task successes are stored");
    assert!(read_metrics(&dir)
        .unwrap()
        .iter()
        .all(|m| m.start_stage.is_none()));
    let text = std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap();
    assert!(!text.contains("start_stage"));
    let (_, extras) = Checkpoint::load_with_extras(&dir.join(CHECKPOINT_FILE)).unwrap();
    assert!(extras.start_stage.is_none());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_trajectory_batch_keeps_a_start_leg_pose() {
    use nalgebra::Point2;
    use wheelleg_runtime::action::{Action, Step};
    use wheelleg_sim::env::EnvConfig;
    use wheelleg_sim::scenario::Scenario;
    use wheelleg_sim::state::RobotState;
    use wheelleg_trainer::trajectory::randomize::{randomize_batch_with, RandomizeConfig};
    use wheelleg_trainer::trajectory::Trajectory;

    // Spread wide and low, two steps from the target.
    let scenario = Scenario {
        name: "spread-start".into(),
        start: RobotState {
            clearance_steps: -2,
            track_steps: 10,
            ..RobotState::new(
                Point2::new(0.025, 0.025),
                0,
                &wheelleg_runtime::action::ActionLattice::PAPER,
            )
        },
        target: Point2::new(0.175, 0.025),
        obstacles: Vec::new(),
    };
    let forward = Action {
        move_x: Step::Plus,
        ..Action::default()
    };
    let trajectory = Trajectory::new(scenario, vec![forward; 2], Behaviour::SpreadOver);
    let dir = temp_dir("stage-batch");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("one.wltb");
    let config = RandomizeConfig {
        per_trajectory: 0,
        include_original: true,
        env: EnvConfig::default(),
        ..RandomizeConfig::default()
    };
    randomize_batch_with(std::slice::from_ref(&trajectory), &config, &path, |_| {}).unwrap();
    let batch = TrajectoryBatch::load(&path).unwrap();
    assert_eq!(batch.len(), 1, "{:?}", batch.sources());
    let stored = batch.trajectory(0).unwrap();
    assert_eq!(stored.scenario, trajectory.scenario);
    let replay = stored.replay(batch.env_config().unwrap()).unwrap();
    assert!(replay.success() && replay.collision_free());
    let _ = std::fs::remove_dir_all(&dir);
}
