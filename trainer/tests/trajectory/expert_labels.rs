//! Expert labels: the states the on-board stack visits with the shipped policy, labelled by the
//! planner or by the full stack; every label replays clean from its moved start, the file is the
//! same for a seed and any thread count, and a cut file resumes to the same bytes.

use super::*;
use wheelleg_sim::generate::{generate_many, SceneRobot};
use wheelleg_stack::policy::{BatchPolicy, Int8Policy, LOG_PROBS};
use wheelleg_trainer::trajectory::batch_file::{parse_header, scan_chunks, CHUNK_PREFIX_LEN};
use wheelleg_trainer::trajectory::expert_labels::{
    label_batch, visited_states, LabelConfig, LabelStats, EXPERT_BATCH_STATES,
};

fn shipped_weights() -> Vec<u8> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../weights/policy.wlw");
    std::fs::read(path).unwrap()
}

/// Three complex scenes of a seed no held-out or validation set uses.
fn scenes() -> Vec<Scenario> {
    generate_many(
        SceneRobot::shipped(),
        SceneKind::Complex,
        &mut ChaCha8Rng::seed_from_u64(4_000_017),
        3,
    )
}

fn small_chunks() -> LabelConfig {
    LabelConfig {
        seed: 4_000_017,
        every: 3,
        planner_expansions: 3_000,
        chunk_states: 4,
        ..LabelConfig::default()
    }
}

fn label(config: &LabelConfig, out: &std::path::Path) -> LabelStats {
    let bytes = shipped_weights();
    let policy = Int8Policy::from_bytes(&bytes).unwrap();
    label_batch(&policy, &scenes(), config, out, |_| {}).unwrap()
}

#[test]
fn every_label_replays_clean_to_the_target_from_its_visited_state() {
    let dir = scratch("labels");
    let out = dir.join("labels.wltb");
    let stats = label(&small_chunks(), &out);
    let batch = TrajectoryBatch::load(&out).unwrap();
    assert_eq!(stats.episodes, 3);
    assert_eq!(batch.sources().len() as u64, stats.states);
    assert_eq!(batch.len() as u64, stats.labelled);
    assert!(stats.labelled >= 3, "{stats:?}");
    assert_eq!(
        stats.labelled + stats.no_way + stats.out_of_budget + stats.unusable,
        stats.states
    );
    assert_labels_replay_clean(&batch);
}

/// Every label of `batch` replays collision-free to the target from its start, and its scene is
/// its episode's, started elsewhere.
fn assert_labels_replay_clean(batch: &TrajectoryBatch) {
    let env = batch.env_config().unwrap();
    let scenes = scenes();
    for i in 0..batch.len() {
        let label = batch.trajectory(i).unwrap();
        assert_eq!(label.behaviour, Behaviour::Around);
        let replay = label.replay(env).unwrap();
        assert!(
            replay.success(),
            "{}: {:?}",
            label.scenario.name,
            replay.status
        );
        assert!(replay.collision_free() && replay.invalid_actions == 0);
        assert_eq!(replay.steps as usize, label.actions.len());
        // The label's scene is its episode's, started elsewhere.
        let scene = scenes
            .iter()
            .find(|s| label.scenario.name.starts_with(&format!("{}@", s.name)))
            .unwrap();
        assert_eq!(label.scenario.target, scene.target);
        let mut obstacles = label.scenario.obstacles.clone();
        let mut expected = scene.obstacles.clone();
        let key = |o: &Obstacle| (o.centre.x.to_bits(), o.centre.y.to_bits(), o.kind as u8);
        obstacles.sort_by_key(key);
        expected.sort_by_key(key);
        assert_eq!(obstacles, expected);
    }
    // Each scene's start is a visited state (the first decision's).
    assert!(batch.sources().iter().any(|s| s.name.ends_with("@0")));
}

#[test]
fn the_full_stack_labels_the_states_it_reaches_the_target_from() {
    let dir = scratch("labels-full-stack");
    let out = dir.join("labels.wltb");
    let config = LabelConfig {
        expert_stack: Some(wheelleg_stack::Preset::Full.config()),
        ..small_chunks()
    };
    let stats = label(&config, &out);
    let batch = TrajectoryBatch::load(&out).unwrap();
    assert_eq!(batch.sources().len() as u64, stats.states);
    assert_eq!(batch.len() as u64, stats.labelled);
    assert_eq!(stats.no_way + stats.out_of_budget, 0, "{stats:?}");
    assert_eq!(
        stats.labelled + stats.expert_failed + stats.unusable,
        stats.states
    );
    // The shipped policy's full stack succeeds from most states its on-board stack visits.
    assert!(2 * stats.labelled > stats.states, "{stats:?}");
    assert_labels_replay_clean(&batch);
    // Labelling again with the planner is another file, refused in its place.
    let bytes = shipped_weights();
    let policy = Int8Policy::from_bytes(&bytes).unwrap();
    let planner = small_chunks();
    let refused = label_batch(&policy, &scenes(), &planner, &out, |_| {})
        .unwrap_err()
        .to_string();
    assert!(
        refused.contains("delete it or choose another --out"),
        "{refused}"
    );
}

#[test]
fn labels_are_the_same_for_a_seed_and_any_thread_count() {
    let dir = scratch("labels-seed");
    let one = dir.join("one.wltb");
    let two = dir.join("two.wltb");
    label(
        &LabelConfig {
            threads: 1,
            ..small_chunks()
        },
        &one,
    );
    label(
        &LabelConfig {
            threads: 2,
            ..small_chunks()
        },
        &two,
    );
    assert_eq!(std::fs::read(one).unwrap(), std::fs::read(two).unwrap());
}

/// The full stack drives batches of states on as many threads as asked, and the file is the
/// same for any thread count.
#[test]
fn full_stack_labels_are_the_same_for_any_thread_count() {
    let dir = scratch("labels-full-stack-threads");
    let bytes = shipped_weights();
    let policy = Int8Policy::from_bytes(&bytes).unwrap();
    let scenes = generate_many(
        SceneRobot::shipped(),
        SceneKind::Complex,
        &mut ChaCha8Rng::seed_from_u64(4_000_018),
        8,
    );
    let config = |threads| LabelConfig {
        expert_stack: Some(wheelleg_stack::Preset::Full.config()),
        every: 1,
        threads,
        chunk_states: 256,
        ..small_chunks()
    };
    let mut files = Vec::new();
    for threads in [1, 2] {
        let out = dir.join(format!("threads-{threads}.wltb"));
        let stats = label_batch(&policy, &scenes, &config(threads), &out, |_| {}).unwrap();
        // More than one batch, so that two threads share the work.
        assert!(
            stats.states > 2 * EXPERT_BATCH_STATES as u64,
            "{} states",
            stats.states
        );
        files.push(std::fs::read(out).unwrap());
    }
    // Not assert_eq: a difference would print two files of bytes.
    assert!(
        files[0] == files[1],
        "one thread and two wrote different files"
    );
}

#[test]
fn a_cut_labelling_run_resumes_to_the_same_file() {
    let dir = scratch("labels-resume");
    let whole = dir.join("whole.wltb");
    label(&small_chunks(), &whole);
    let bytes = std::fs::read(&whole).unwrap();
    let (header, start) = parse_header(&bytes).unwrap();
    let scan = scan_chunks(&bytes, &header, start);
    assert!(scan.chunks.len() >= 3, "{} chunks", scan.chunks.len());
    // Header, the first chunk whole and the second cut in half: a run killed while writing.
    let first_len = {
        let len = u32::from_le_bytes(bytes[start..start + 4].try_into().unwrap()) as usize;
        CHUNK_PREFIX_LEN + len
    };
    let cut = start + first_len + 10;
    let resumed = dir.join("resumed.wltb");
    std::fs::write(partial_path(&resumed), &bytes[..cut]).unwrap();
    let stats = label(&small_chunks(), &resumed);
    assert_eq!(stats.resumed_at_state, scan.chunks[0].sources.len() as u64);
    assert_eq!(stats.discarded_tail_bytes, 10);
    assert_eq!(stats.planned_here, stats.states - stats.resumed_at_state);
    assert_eq!(std::fs::read(&resumed).unwrap(), bytes);
    assert!(!partial_path(&resumed).exists());
    // Done: a run again plans nothing; another budget is refused, naming the fingerprint.
    assert_eq!(label(&small_chunks(), &resumed).planned_here, 0);
    let policy_bytes = shipped_weights();
    let policy = Int8Policy::from_bytes(&policy_bytes).unwrap();
    let other = LabelConfig {
        planner_expansions: 2_000,
        ..small_chunks()
    };
    let e = label_batch(&policy, &scenes(), &other, &resumed, |_| {}).unwrap_err();
    assert!(
        matches!(
            &e,
            wheelleg_trainer::TrainError::LabelsDiffer {
                field: "sources_fingerprint",
                ..
            }
        ),
        "{e}"
    );
}

/// Always asks for the same action: its episodes never arrive.
struct Stubborn;

impl BatchPolicy for Stubborn {
    fn log_probs(&self, _: &[f32], _: &[f32], n: usize) -> Result<Vec<f32>, String> {
        let head = [0.0, -1.0, -2.0];
        Ok(head.iter().copied().cycle().take(n * LOG_PROBS).collect())
    }

    fn kind(&self) -> &'static str {
        "stubborn"
    }
}

#[test]
fn failed_episodes_give_every_state_and_successful_ones_every_kth() {
    let scenes = scenes();
    let every = |policy: &dyn BatchPolicy, k: usize| {
        let config = LabelConfig {
            every: k,
            ..small_chunks()
        };
        visited_states(policy, &scenes, &config).unwrap()
    };
    let failing = every(&Stubborn, 4);
    assert_eq!(failing.successes, 0);
    assert_eq!(failing.states, every(&Stubborn, 1).states);
    let bytes = shipped_weights();
    let shipped = Int8Policy::from_bytes(&bytes).unwrap();
    let all = every(&shipped, 1);
    let some = every(&shipped, 4);
    assert_eq!(all.successes, some.successes);
    assert!(all.successes > 0);
    let per_scene = |v: &[Trajectory], s: &Scenario| {
        v.iter()
            .filter(|t| t.scenario.name.starts_with(&format!("{}@", s.name)))
            .count()
    };
    for scene in &scenes {
        let (n, k) = (
            per_scene(&all.states, scene),
            per_scene(&some.states, scene),
        );
        assert!(k == n || k == n.div_ceil(4), "{}: {k} of {n}", scene.name);
    }
    // A state is offered once per episode, however often the episode stood there.
    for scene in &scenes {
        let starts: Vec<RobotState> = all
            .states
            .iter()
            .filter(|t| t.scenario.name.starts_with(&format!("{}@", scene.name)))
            .map(|t| t.scenario.start)
            .collect();
        for (i, a) in starts.iter().enumerate() {
            assert!(!starts[i + 1..].contains(a));
        }
    }
    // Seeds of the held-out and validation sets are refused.
    let reserved = LabelConfig {
        seed: 3_000_000,
        ..small_chunks()
    };
    assert!(visited_states(&shipped, &scenes, &reserved)
        .unwrap_err()
        .to_string()
        .contains("validation"));
}
