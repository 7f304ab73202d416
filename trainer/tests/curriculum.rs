//! The paper's pipeline end to end on a tiny budget: secondary policies store successful
//! trajectories, randomization turns them into a batch of replays that all still succeed, the
//! primary policy trains on complex scenes with replayed samples, and `all` run again resumes
//! without redoing finished stages; a primary fine-tuned from a checkpoint on expert labels.
//!
//! Run in release: `cargo test --release -p wheelleg-trainer --test curriculum`.

use std::path::PathBuf;
use wheelleg_sim::generate::Behaviour;
use wheelleg_trainer::checkpoint::Checkpoint;
use wheelleg_trainer::config::TrainConfig;
use wheelleg_trainer::curriculum::{
    run_all, run_primary_with, secondary_dir, stored_trajectories, CurriculumOptions,
    PrimaryInputs, BATCH_FILE, PRIMARY_DIR,
};
use wheelleg_trainer::runner::{
    read_metrics, train_stage, RunOptions, StageInputs, CHECKPOINT_FILE,
};
use wheelleg_trainer::trajectory::batch_file::TrajectoryBatch;
use wheelleg_trainer::trajectory::expert_labels::{label_batch, LabelConfig};
use wheelleg_trainer::TrainError;

fn tiny_config() -> TrainConfig {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/smoke.toml");
    let mut config = TrainConfig::load(std::path::Path::new(path)).unwrap();
    config.run.num_envs = 20;
    config.run.steps_per_iteration = 1000;
    config.run.total_env_steps = 2000;
    config.curriculum.behaviours = vec!["straight".into(), "lift".into()];
    config.curriculum.secondary_steps_per_iteration = 1000;
    config.curriculum.secondary_env_steps = 10_000;
    config.curriculum.keep_trajectories = 40;
    config.curriculum.randomizations = 3;
    config.curriculum.replay_steps_per_iteration = 200;
    config.validate().unwrap();
    config
}

#[test]
fn the_whole_pipeline_runs_and_resumes() {
    let out = std::env::temp_dir().join(format!("wheelleg-curriculum-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    // Straight alone: at this budget the other behaviours store no episode, and a batch
    // without one of its behaviours is refused (`stored_trajectories`).
    let mut config = tiny_config();
    config.curriculum.behaviours = vec!["straight".into()];
    let opts = CurriculumOptions {
        out: out.clone(),
        seed: 5,
        progress: false,
        stop_at_env_steps: None,
    };
    let summary = run_all(&config, &opts).unwrap();
    assert_eq!(summary.env_steps, 2000);

    // The secondary policy ran its budget and kept successful trajectories.
    let dir = secondary_dir(&out, Behaviour::Straight);
    let c = Checkpoint::load(&dir.join(CHECKPOINT_FILE)).unwrap();
    assert_eq!(c.env_steps, 10_000);
    assert!(!read_metrics(&dir).unwrap().is_empty());
    let sources = stored_trajectories(&config, &out).unwrap();
    assert!(
        !sources.is_empty() && sources.len() <= 40,
        "{}",
        sources.len()
    );

    // Every trajectory of the batch replays to success without a collision, under the
    // batch's own episode rules.
    let batch = TrajectoryBatch::load(&out.join(BATCH_FILE)).unwrap();
    assert!(
        batch.len() >= sources.len(),
        "{} < {}",
        batch.len(),
        sources.len()
    );
    for i in 0..batch.len() {
        let replay = batch
            .trajectory(i)
            .unwrap()
            .replay(batch.env_config().unwrap())
            .unwrap();
        assert!(
            replay.success() && replay.collision_free(),
            "trajectory {i}"
        );
    }

    // The primary run logged its iterations, each with where its time went (the primary
    // replays the batch); running `all` again trains nothing more.
    let primary = out.join(PRIMARY_DIR);
    let metrics = read_metrics(&primary).unwrap();
    assert_eq!(metrics.len(), 2);
    for m in &metrics {
        let t = m.time;
        assert!(
            t.act_s > 0.0 && t.env_s > 0.0 && t.replay_s > 0.0 && t.update_s > 0.0,
            "{t:?}"
        );
    }
    let again = run_all(&config, &opts).unwrap();
    assert_eq!(again.env_steps, 2000);
    assert!(again.last.is_none());
    assert_eq!(read_metrics(&primary).unwrap().len(), 2);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn the_primary_stage_names_the_missing_batch() {
    let out = std::env::temp_dir().join(format!("wheelleg-nobatch-{}", std::process::id()));
    let opts = CurriculumOptions {
        out: PathBuf::from(&out),
        seed: 0,
        progress: false,
        stop_at_env_steps: None,
    };
    let e = wheelleg_trainer::curriculum::run_primary(&tiny_config(), &opts)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("batch.wltb") && e.contains("wheelleg train randomize"),
        "{e}"
    );
}

#[test]
fn a_behaviour_given_its_own_budget_is_continued_alone() {
    let out = std::env::temp_dir().join(format!("wheelleg-budget-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let mut config = tiny_config();
    let opts = CurriculumOptions {
        out: out.clone(),
        seed: 3,
        progress: false,
        stop_at_env_steps: None,
    };
    let env_steps = |behaviour| {
        Checkpoint::load(&secondary_dir(&out, behaviour).join(CHECKPOINT_FILE))
            .unwrap()
            .env_steps
    };
    wheelleg_trainer::curriculum::run_secondary(&config, &opts).unwrap();
    assert_eq!(env_steps(Behaviour::LiftOver), 10_000);
    // Lift gets a larger budget of its own: run again, only lift trains on.
    config
        .curriculum
        .secondary_env_steps_by_behaviour
        .insert("lift".into(), 13_000);
    config.validate().unwrap();
    let straight_before = read_metrics(&secondary_dir(&out, Behaviour::Straight)).unwrap();
    wheelleg_trainer::curriculum::run_secondary(&config, &opts).unwrap();
    assert_eq!(env_steps(Behaviour::Straight), 10_000);
    assert_eq!(env_steps(Behaviour::LiftOver), 13_000);
    assert_eq!(
        read_metrics(&secondary_dir(&out, Behaviour::Straight)).unwrap(),
        straight_before
    );
    // A budget for a behaviour the run does not train is refused, naming the key.
    config
        .curriculum
        .secondary_env_steps_by_behaviour
        .insert("squeeze".into(), 1);
    let e = config.validate().unwrap_err();
    assert!(
        matches!(e, wheelleg_trainer::config::ConfigError::Invalid(_)),
        "{e}"
    );
    assert!(
        e.to_string().contains("secondary_env_steps_by_behaviour"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&out);
}

/// Expert labels of one complex scene of `seed`, driven by the shipped policy under `config`'s
/// episode rules.
fn labels(config: &TrainConfig, seed: u64, out: &std::path::Path) -> TrajectoryBatch {
    use rand::SeedableRng;
    let bytes = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../weights/policy.wlw"
    ))
    .unwrap();
    let policy = wheelleg_stack::policy::Int8Policy::from_bytes(&bytes).unwrap();
    let scenes = wheelleg_sim::generate::generate_many(
        wheelleg_sim::generate::SceneRobot::shipped(),
        wheelleg_sim::generate::SceneKind::Complex,
        &mut rand_chacha::ChaCha8Rng::seed_from_u64(seed),
        1,
    );
    let label = LabelConfig {
        env: config.episode_rules().unwrap(),
        seed,
        planner_expansions: 2_000,
        ..LabelConfig::default()
    };
    label_batch(&policy, &scenes, &label, out, |_| {}).unwrap();
    TrajectoryBatch::load(out).unwrap()
}

#[test]
fn a_primary_fine_tunes_from_a_checkpoint_on_several_batches() {
    let out = std::env::temp_dir().join(format!("wheelleg-finetune-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).unwrap();
    let config = tiny_config();
    let (a, b) = (out.join("a.wltb"), out.join("b.wltb"));
    let (first, second) = (
        labels(&config, 4_000_001, &a),
        labels(&config, 4_000_002, &b),
    );
    assert!(!first.is_empty() && !second.is_empty());

    // Two batches replay as one: the second's trajectories after the first's.
    let mut both = first.clone();
    both.append(second.clone()).unwrap();
    assert_eq!(both.len(), first.len() + second.len());
    assert_eq!(both.trajectory(0), first.trajectory(0));
    assert_eq!(both.trajectory(first.len()), second.trajectory(0));
    assert_eq!(
        both.trajectory(both.len() - 1),
        second.trajectory(second.len() - 1)
    );
    let mut longer = config.clone();
    longer.run.max_episode_steps = 70;
    let foreign = labels(&longer, 4_000_003, &out.join("c.wltb"));
    assert!(both
        .append(foreign)
        .unwrap_err()
        .to_string()
        .contains("different episode rules"));

    let init = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/straight-secondary.ckpt"
    ));
    let opts = CurriculumOptions {
        out: out.clone(),
        seed: 2,
        progress: false,
        stop_at_env_steps: None,
    };
    let inputs = PrimaryInputs {
        init: Some(init.clone()),
        batches: vec![a.clone(), b.clone()],
        labels: Vec::new(),
    };
    let mut narrow = config.clone();
    narrow.network.hidden = vec![64];
    let e = run_primary_with(&narrow, &opts, &inputs).unwrap_err();
    assert!(
        matches!(&e, TrainError::NetworkMismatch { path, .. } if *path == init),
        "{e}"
    );
    assert!(e.to_string().contains("[network]"), "{e}");

    let summary = run_primary_with(&config, &opts, &inputs).unwrap();
    assert_eq!(summary.env_steps, 2000);
    // Two updates move the checkpoint's network a little, far less than a fresh start is
    // from it.
    let head = |path: &std::path::Path| {
        Checkpoint::load(path)
            .unwrap()
            .network
            .to_network()
            .unwrap()
            .action_head
            .weights
    };
    let distance = |x: &[f32], y: &[f32]| -> f32 {
        x.iter()
            .zip(y)
            .map(|(p, q)| (p - q) * (p - q))
            .sum::<f32>()
            .sqrt()
    };
    let (before, after) = (head(&init), head(&summary.checkpoint));
    let fresh = out.join("fresh");
    let fresh_summary = run_primary_with(
        &config,
        &CurriculumOptions {
            out: fresh,
            ..opts.clone()
        },
        &PrimaryInputs {
            init: None,
            ..inputs.clone()
        },
    )
    .unwrap();
    let scratch = head(&fresh_summary.checkpoint);
    assert!(
        distance(&after, &before) < 0.5 * distance(&scratch, &before),
        "{} vs {}",
        distance(&after, &before),
        distance(&scratch, &before)
    );

    // Expert labels given apart from the batch are replayed and cloned too: the same run with
    // them ends elsewhere; with no label steps per iteration they are refused, not ignored.
    let with_labels = |config: &TrainConfig, dir: &str| {
        run_primary_with(
            config,
            &CurriculumOptions {
                out: out.join(dir),
                ..opts.clone()
            },
            &PrimaryInputs {
                init: Some(init.clone()),
                batches: vec![a.clone()],
                labels: vec![b.clone()],
            },
        )
    };
    let without = run_primary_with(
        &config,
        &CurriculumOptions {
            out: out.join("without-labels"),
            ..opts.clone()
        },
        &PrimaryInputs {
            init: Some(init.clone()),
            batches: vec![a.clone()],
            labels: Vec::new(),
        },
    )
    .unwrap();
    let labelled = with_labels(&config, "with-labels").unwrap();
    assert!(
        distance(&head(&labelled.checkpoint), &head(&without.checkpoint)) > 0.0,
        "the labels changed nothing"
    );
    let mut no_label_steps = config.clone();
    no_label_steps.curriculum.label_steps_per_iteration = 0;
    let e = with_labels(&no_label_steps, "no-label-steps").unwrap_err();
    assert!(
        matches!(
            e,
            TrainError::Setting {
                key: "curriculum.label_steps_per_iteration",
                ..
            }
        ),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_stage_that_has_learnt_stops_before_its_budget_and_stays_stopped() {
    // A secondary's stage as the curriculum runs it: straight scenes, its trajectories kept.
    let mut config = tiny_config();
    config.run.scene_kind = "straight".into();
    config.run.total_env_steps = 20_000;
    let run = |config: &TrainConfig, name: &str, resume: bool| {
        let out = std::env::temp_dir().join(format!("wheelleg-{name}-{}", std::process::id()));
        if !resume {
            let _ = std::fs::remove_dir_all(&out);
        }
        let opts = RunOptions {
            out: out.clone(),
            seed: 5,
            resume,
            progress: false,
            max_iterations: None,
            stop_at_env_steps: None,
            kind: "test".into(),
        };
        let inputs = StageInputs {
            record: Some(Behaviour::Straight),
            keep_trajectories: 1,
            ..StageInputs::default()
        };
        train_stage(config, &opts, inputs).unwrap();
        let success: Vec<(u64, f32)> = read_metrics(&out)
            .unwrap()
            .iter()
            .map(|m| (m.env_steps, m.success_rate))
            .collect();
        (out, success)
    };
    // The same run without the rule, to its budget: the rate its best two iterations in a row
    // among the first ten reach, and the first iteration that completes such a pair.
    let (whole, reference) = run(&config, "learnt-whole", false);
    assert_eq!(reference.len(), 20);
    let pair = |i: usize| reference[i - 1].1.min(reference[i].1);
    let rate = (1..10).map(pair).fold(0.0f32, f32::max);
    assert!(rate > 0.0, "straight scenes succeed within ten iterations");
    let stop = (1..10).find(|&i| pair(i) >= rate).unwrap();

    config.run.stop_success_rate = rate;
    config.run.stop_window = 2;
    config.validate().unwrap();
    let (early, success) = run(&config, "learnt-early", false);
    assert_eq!(success, reference[..=stop], "the same run, ended early");
    let checkpoint = Checkpoint::load(&early.join(CHECKPOINT_FILE)).unwrap();
    assert_eq!(checkpoint.env_steps, reference[stop].0);
    // Resumed (as `train all` run again does): the stage has learnt, nothing more trains.
    let (_, again) = run(&config, "learnt-early", true);
    assert_eq!(again, reference[..=stop]);
    for out in [whole, early] {
        let _ = std::fs::remove_dir_all(&out);
    }
}
