//! A run's metrics log, `metrics.jsonl`: one JSON object per iteration, appended as the run
//! goes and cut back to the checkpoint on resume.

use super::METRICS_FILE;
use crate::error::TrainError;
use crate::ppo::UpdateStats;
use crate::vec_env::EpisodeStats;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;

/// One iteration's line in `metrics.jsonl`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct IterationMetrics {
    /// Iteration number, from 1.
    pub iteration: u64,
    /// Environment steps taken so far.
    pub env_steps: u64,
    /// Episodes finished during the iteration.
    pub episodes: usize,
    /// Mean undiscounted return of those episodes.
    pub mean_return: f32,
    /// Fraction that reached the target.
    pub success_rate: f32,
    /// Fraction that reached the target without any collision.
    pub collision_free_rate: f32,
    /// Mean steps of the successful episodes (path length); none without successes.
    pub mean_success_steps: Option<f32>,
    /// PPO statistics.
    pub update: UpdateStats,
    /// Environment steps per second of the whole iteration (rollout + update).
    pub steps_per_s: f32,
    /// Where the iteration's time went.
    #[serde(default)]
    pub time: IterationTime,
    /// Seconds of training so far.
    pub elapsed_s: f64,
    /// Start stage of the scenes drawn during the iteration (runs with the start-stage
    /// curriculum only; `run.start_stage`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_stage: Option<f32>,
    /// Success rate of the iteration's episodes that started at that stage.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_stage_success_rate: Option<f32>,
}

/// Where one iteration's wall time went, in seconds: what a change to training speed is
/// measured against (`wheelleg train`'s summary adds them up over a run).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct IterationTime {
    /// The policy's forward passes of the rollout (acting, and the bootstrap values).
    pub act_s: f64,
    /// The environments' steps (simulation, rewards, observations).
    pub env_s: f64,
    /// Replayed samples re-rendered and scored (Algorithm 2; 0 without a batch).
    pub replay_s: f64,
    /// The PPO update (forward, backward, optimizer) over all samples.
    pub update_s: f64,
}

impl std::ops::Add for IterationTime {
    type Output = IterationTime;

    fn add(self, other: IterationTime) -> IterationTime {
        IterationTime {
            act_s: self.act_s + other.act_s,
            env_s: self.env_s + other.env_s,
            replay_s: self.replay_s + other.replay_s,
            update_s: self.update_s + other.update_s,
        }
    }
}

/// Episode outcomes summarised.
pub fn summarise(episodes: &[EpisodeStats]) -> (f32, f32, f32, Option<f32>) {
    let n = episodes.len().max(1) as f32;
    let successes: Vec<&EpisodeStats> = episodes.iter().filter(|e| e.success).collect();
    let mean_return = episodes.iter().map(|e| e.return_sum).sum::<f32>() / n;
    let success = successes.len() as f32 / n;
    let collision_free = successes.iter().filter(|e| e.collisions == 0).count() as f32 / n;
    let steps = (!successes.is_empty())
        .then(|| successes.iter().map(|e| e.steps as f32).sum::<f32>() / successes.len() as f32);
    (mean_return, success, collision_free, steps)
}

pub(super) fn append_metrics(path: &Path, m: &IterationMetrics) -> Result<(), TrainError> {
    let line = serde_json::to_string(m).map_err(|error| TrainError::Metrics {
        path: path.to_path_buf(),
        line: None,
        error,
    })?;
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| TrainError::io(path, "open", e))?;
    writeln!(f, "{line}").map_err(|e| TrainError::io(path, "write", e))
}

/// Drops metric lines after `iteration` (written after the checkpoint a resume starts from), so
/// the log has each iteration exactly once.
pub(super) fn truncate_metrics(path: &Path, iteration: u64) -> Result<(), TrainError> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(());
    };
    let kept: String = text
        .lines()
        .filter(|l| {
            serde_json::from_str::<IterationMetrics>(l).is_ok_and(|m| m.iteration <= iteration)
        })
        .map(|l| format!("{l}\n"))
        .collect();
    wheelleg_sim::atomic_write(path, kept.as_bytes())
        .map_err(|e| TrainError::io(path, "rewrite", e))
}

/// Reads a run's metrics (for plots).
pub fn read_metrics(run: &Path) -> Result<Vec<IterationMetrics>, TrainError> {
    let path = run.join(METRICS_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| TrainError::io(&path, "read", e))?;
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            serde_json::from_str(l).map_err(|error| TrainError::Metrics {
                path: path.clone(),
                line: Some(i + 1),
                error,
            })
        })
        .collect()
}
