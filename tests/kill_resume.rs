//! Training survives being killed at any point: `wheelleg train baseline` is killed
//! (SIGKILL, like a crash or the OOM killer) again and again at seeded moments, some random,
//! some the instant a checkpoint write starts, some the instant an iteration's metrics line
//! lands, and resumed with `--resume` each time. After every kill the run folder must be
//! consistent (the checkpoint, if any, loads; the metrics log is iterations 1..k with at most
//! a torn last line); the finished run must be complete (every iteration logged exactly once,
//! in order, the checkpoint at the end of the budget, no temporary left) and identical to an
//! uninterrupted run of the same seed (docs/robustness.md).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use wheelleg_trainer::checkpoint::Checkpoint;
use wheelleg_trainer::config::TrainConfig;
use wheelleg_trainer::runner::{
    read_metrics, train, IterationMetrics, RunOptions, CHECKPOINT_FILE, METRICS_FILE,
};

/// configs/smoke.toml cut down to seconds: 30 iterations of 200 steps, a checkpoint every
/// second iteration (so a kill usually loses work that must be redone), the shipped network.
const CONFIG: &str = r#"
[run]
scene_kind = "straight"
steps_per_iteration = 200
num_envs = 10
total_env_steps = 6000
max_episode_steps = 50
checkpoint_interval = 2
threads = 1
backend = "flex"

[ppo]
learning_rate = 0.0025
epochs = 4
minibatch_size = 100
entropy_coef = 0.0
gamma = 0.95
gae_lambda = 0.9
target_kl = 0.05
"#;
const ITERATIONS: u64 = 30;
const SEED: u64 = 5;
/// Kills before the run is let finish.
const KILLS: usize = 12;

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("kill-resume-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn spawn(config: &Path, out: &Path, resume: bool) -> Child {
    let mut command = Command::new(env!("CARGO_BIN_EXE_wheelleg"));
    command
        .args(["train", "baseline", "--quiet", "--seed", &SEED.to_string()])
        .arg("--config")
        .arg(config)
        .arg("--out")
        .arg(out)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    if resume {
        command.arg("--resume");
    }
    command.spawn().unwrap()
}

/// The metrics log as it stands: complete lines parsed, plus whether a torn line follows.
fn metrics_lines(run: &Path) -> (Vec<IterationMetrics>, bool) {
    let Ok(text) = std::fs::read_to_string(run.join(METRICS_FILE)) else {
        return (Vec::new(), false);
    };
    let mut lines: Vec<&str> = text.split('\n').collect();
    // After the last newline: empty, or a line the kill cut short.
    let tail = lines.pop().unwrap_or("");
    let parsed = lines
        .iter()
        .enumerate()
        .map(|(i, l)| {
            serde_json::from_str(l).unwrap_or_else(|e| panic!("metrics line {}: {e}: {l}", i + 1))
        })
        .collect();
    (parsed, !tail.is_empty())
}

fn assert_contiguous(metrics: &[IterationMetrics], what: &str) {
    let iterations: Vec<u64> = metrics.iter().map(|m| m.iteration).collect();
    let want: Vec<u64> = (1..=metrics.len() as u64).collect();
    assert_eq!(iterations, want, "{what}: iterations not 1..k exactly once");
    for m in metrics {
        assert_eq!(m.env_steps, m.iteration * 200, "{what}: {m:?}");
    }
}

/// What must hold in the run folder at any instant a kill can leave it in.
fn assert_consistent(run: &Path, what: &str) -> Option<u64> {
    let (metrics, _torn) = metrics_lines(run);
    assert_contiguous(&metrics, what);
    let path = run.join(CHECKPOINT_FILE);
    if !path.exists() {
        return None;
    }
    let checkpoint = Checkpoint::load(&path).unwrap_or_else(|e| panic!("{what}: {e}"));
    checkpoint.network.to_network().unwrap();
    // The checkpoint is written after its iteration's metrics line.
    assert!(
        metrics.len() as u64 >= checkpoint.iteration,
        "{what}: checkpoint at {} but only {} metrics lines",
        checkpoint.iteration,
        metrics.len()
    );
    Some(checkpoint.iteration)
}

/// How a kill picks its moment.
#[derive(Clone, Copy, Debug)]
enum Moment {
    /// A random time after the start (start-up, rollout, update, writes: anywhere).
    Random(Duration),
    /// The instant the checkpoint's temporary file appears (a write in progress).
    CheckpointWrite,
    /// The instant a new metrics line appears (between the log and the checkpoint).
    MetricsLine,
}

/// Waits for `moment` and kills the child; `false` if the child finished first.
fn kill_at(child: &mut Child, run: &Path, moment: Moment) -> bool {
    let start = Instant::now();
    let temp = run.join(format!(".{CHECKPOINT_FILE}.tmp"));
    let metrics = run.join(METRICS_FILE);
    let metrics_len = || std::fs::metadata(&metrics).map_or(0, |m| m.len());
    let len_at_start = metrics_len();
    loop {
        if child.try_wait().unwrap().is_some() {
            return false;
        }
        let now = match moment {
            Moment::Random(after) => start.elapsed() >= after,
            Moment::CheckpointWrite => temp.exists(),
            Moment::MetricsLine => metrics_len() > len_at_start,
        };
        if now {
            // SIGKILL: no destructor, no flush, no chance to finish the write.
            let _ = child.kill();
            child.wait().unwrap();
            return true;
        }
        if matches!(moment, Moment::Random(_)) {
            std::thread::sleep(Duration::from_millis(1));
        }
        // Busy-wait otherwise: a checkpoint write lasts milliseconds.
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "{moment:?} never came"
        );
    }
}

#[test]
fn a_training_run_killed_at_any_moment_resumes_to_the_same_result() {
    let started = Instant::now();
    let dir = scratch("run");
    let config_path = dir.join("tiny.toml");
    std::fs::write(&config_path, CONFIG).unwrap();
    let run = dir.join("killed");
    let config = TrainConfig::load(&config_path).unwrap();
    // The uninterrupted reference run first: its duration scales the random kill moments, so
    // they land inside a run on any machine (fixed 50 ms to 2.5 s windows stopped landing once
    // the native conv kernel made the whole run shorter than 2.5 s).
    let whole = dir.join("whole");
    let whole_started = Instant::now();
    let reference = train(
        &config,
        &RunOptions {
            out: whole.clone(),
            seed: SEED,
            resume: false,
            progress: false,
            max_iterations: None,
            stop_at_env_steps: None,
            kind: "baseline".into(),
        },
    )
    .unwrap();
    let whole_run = whole_started.elapsed();
    let mut rng = ChaCha8Rng::seed_from_u64(20_240_607);
    let (mut kills, mut during_write, mut before_first_checkpoint) = (0, 0, 0);
    let mut resumed_from = Vec::new();
    for k in 0..KILLS {
        let checkpoint = run.join(CHECKPOINT_FILE).exists();
        if !checkpoint && run.exists() && k > 0 {
            // Killed before the first checkpoint: there is nothing to resume, and --resume
            // says so rather than starting a different run.
            let out = spawn(&config_path, &run, true).wait_with_output().unwrap();
            assert!(!out.status.success());
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert!(stderr.contains(CHECKPOINT_FILE), "{stderr}");
            before_first_checkpoint += 1;
        }
        let mut child = spawn(&config_path, &run, checkpoint);
        let moment = match k % 3 {
            0 => Moment::Random(whole_run.mul_f64(rng.random_range(0.02..0.25))),
            1 => Moment::CheckpointWrite,
            _ => Moment::MetricsLine,
        };
        if !kill_at(&mut child, &run, moment) {
            let out = child.wait_with_output().unwrap();
            assert!(out.status.success(), "{:?}", out);
            break;
        }
        kills += 1;
        let temp = run.join(format!(".{CHECKPOINT_FILE}.tmp"));
        if temp.exists() {
            during_write += 1;
        }
        let at = assert_consistent(&run, &format!("after kill {k} ({moment:?})"));
        resumed_from.push(at);
    }
    // Then let it finish.
    let resume = run.join(CHECKPOINT_FILE).exists();
    let out = spawn(&config_path, &run, resume)
        .wait_with_output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // The finished run: complete and clean.
    let (metrics, torn) = metrics_lines(&run);
    assert!(!torn, "the finished log ends with a torn line");
    assert_contiguous(&metrics, "finished run");
    assert_eq!(metrics.len() as u64, ITERATIONS);
    assert_eq!(read_metrics(&run).unwrap(), metrics);
    let last = Checkpoint::load(&run.join(CHECKPOINT_FILE)).unwrap();
    assert_eq!(last.iteration, ITERATIONS);
    assert_eq!(last.env_steps, ITERATIONS * 200);
    assert_eq!(last.config_toml, config.to_toml());
    assert_eq!(
        std::fs::read_to_string(run.join("config.toml")).unwrap(),
        config.to_toml()
    );
    let leftovers: Vec<String> = std::fs::read_dir(&run)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| name.starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "temporaries left: {leftovers:?}");

    // And it is the run an uninterrupted process makes with the same seed.
    let uninterrupted = Checkpoint::load(&reference.checkpoint).unwrap();
    assert_eq!(last.network, uninterrupted.network);
    assert_eq!(last.adam, uninterrupted.adam);
    assert_eq!(last.envs, uninterrupted.envs);
    assert_eq!(last.sampler_word_pos, uninterrupted.sampler_word_pos);
    let learning = |m: &[IterationMetrics]| {
        m.iter()
            .map(|m| (m.iteration, m.episodes, m.mean_return, m.update.policy_loss))
            .collect::<Vec<_>>()
    };
    assert_eq!(learning(&metrics), learning(&read_metrics(&whole).unwrap()));

    eprintln!(
        "kill/resume: whole run {:.1} s; {kills} kills ({during_write} during a checkpoint write, \
         {before_first_checkpoint} before the first checkpoint), resumed from iterations \
         {resumed_from:?}; {:.1} s",
        whole_run.as_secs_f64(),
        started.elapsed().as_secs_f64()
    );
    // The kills really hit the moments the test is about.
    assert!(kills >= KILLS / 2, "only {kills} kills landed");
    let _ = std::fs::remove_dir_all(&dir);
}
