//! Why training, evaluation, labelling, export or plotting stopped: [`TrainError`].
//!
//! The modules with one way to fail keep their own error ([`ConfigError`], [`CheckpointError`],
//! [`BatchFileError`], [`ReplayError`], [`VecEnvError`], [`QuantizeError`]); a [`TrainError`]
//! wraps any of them (`?` converts) beside what goes wrong between them. Every message names
//! the file, config key or stage it is about, since the command line prints [`Display`] alone.
//!
//! [`Display`]: std::fmt::Display

use crate::checkpoint::CheckpointError;
use crate::config::ConfigError;
use crate::quantize::QuantizeError;
use crate::trajectory::batch_file::BatchFileError;
use crate::trajectory::ReplayError;
use crate::vec_env::VecEnvError;
use std::fmt;
use std::path::PathBuf;
use wheelleg_runtime::model::{InferError, LoadError};
use wheelleg_sim::scenario::ScenarioError;

/// Why a training, evaluation, labelling, export or plotting step failed.
#[derive(Debug)]
pub enum TrainError {
    /// A config does not read or does not validate.
    Config(ConfigError),
    /// A checkpoint does not read, does not fit, or cannot be written.
    Checkpoint(CheckpointError),
    /// A trajectory batch file (or labels file) does not read or cannot be written.
    BatchFile(BatchFileError),
    /// A trajectory does not replay.
    Replay(ReplayError),
    /// The environments cannot be made or restored.
    VecEnv(VecEnvError),
    /// The network cannot be quantized or its weights file encoded.
    Quantize(QuantizeError),
    /// A scene does not start an episode.
    Scenario(ScenarioError),
    /// The decision stack (`wheelleg_stack`) refused its config, or a rollout through it or a
    /// policy behind its interface failed; that crate reports errors as text, kept here as is.
    Stack(String),
    /// The robot's runtime refuses the weights file just exported.
    Refused(LoadError),
    /// The int8 runtime could not evaluate an observation.
    Infer(InferError),
    /// A file or folder could not be read, written or made.
    Io {
        /// The file or folder.
        path: PathBuf,
        /// What was being done to it, a verb phrase: `read`, `write`, `create`, ...
        action: &'static str,
        /// What the system said.
        error: std::io::Error,
    },
    /// A line of a run's metrics log (`metrics.jsonl`) does not parse or cannot be encoded.
    Metrics {
        /// The log.
        path: PathBuf,
        /// The line that does not parse, from 1; `None`: the line being appended.
        line: Option<usize>,
        /// What serde_json said.
        error: serde_json::Error,
    },
    /// The network, an observation or a gradient does not have the shape the computation
    /// needs: a head missing or of another size, operands of a product that do not match, a
    /// gradient that never arrived (the message says which).
    Shape(String),
    /// The backend asked for is not compiled into this build.
    BackendNotBuilt {
        /// The backend, also the name of the cargo feature that compiles it.
        backend: &'static str,
    },
    /// The PPO loss became NaN or infinite: the learning rate is too high for the run.
    Diverged {
        /// The minibatch's policy loss.
        policy_loss: f32,
        /// The minibatch's value loss.
        value_loss: f32,
    },
    /// The quantization-aware fine-tuning's loss became NaN or infinite.
    QatDiverged {
        /// The fine-tuning step, from 0.
        step: usize,
    },
    /// A PPO update was given fewer samples than a minibatch of two needs.
    BatchTooSmall {
        /// Samples in the batch.
        samples: usize,
    },
    /// A trajectory batch has no trajectory at an index it was asked for.
    NoTrajectory {
        /// The index.
        index: usize,
    },
    /// A config key or command-line option whose value cannot be used, alone or with the
    /// other inputs.
    Setting {
        /// The key (`section.key`) or option, as the user writes it.
        key: &'static str,
        /// What is wrong with its value.
        problem: String,
    },
    /// Nothing to work on.
    Nothing {
        /// What is missing (the message is `no {what}`).
        what: &'static str,
    },
    /// A fresh run was asked for in a folder that holds one.
    RunExists {
        /// The run folder.
        out: PathBuf,
    },
    /// A resume with a config that differs from the checkpoint's in keys a resume must keep.
    ConfigChanged {
        /// The checkpoint.
        checkpoint: PathBuf,
        /// The keys that differ, each with both values.
        changes: Vec<String>,
        /// The run's own config, to resume with.
        config: PathBuf,
    },
    /// A resume with another seed than the checkpoint's.
    SeedChanged {
        /// The checkpoint.
        checkpoint: PathBuf,
        /// The seed the checkpoint was written with.
        stored: u64,
        /// The seed asked for.
        requested: u64,
    },
    /// A resume with a start-stage curriculum from a checkpoint that holds no start-stage
    /// state.
    NoStartStage {
        /// The checkpoint.
        checkpoint: PathBuf,
    },
    /// A checkpoint's start-stage state does not fit the run's schedule.
    StartStageMismatch {
        /// The stored stage.
        stage: f32,
        /// The stored window's entries.
        entries: usize,
    },
    /// A checkpoint a run starts from holds another network than the config's `[network]`.
    NetworkMismatch {
        /// The checkpoint.
        path: PathBuf,
        /// Its conv channels.
        conv_channels: Vec<usize>,
        /// Its hidden widths.
        hidden: Vec<usize>,
        /// The config's conv channels.
        config_conv_channels: Vec<usize>,
        /// The config's hidden widths.
        config_hidden: Vec<usize>,
    },
    /// A trajectory batch driven by another robot than the run trains.
    BatchRobot {
        /// The batch, as named to the user.
        what: String,
        /// The robot that drove its trajectories.
        batch_robot: String,
        /// The robot the run trains.
        run_robot: String,
        /// The part of the description that differs.
        part: &'static str,
    },
    /// Two trajectory batches cannot be replayed as one: other episode rules, other robots,
    /// or more scenes together than an index holds (the message says which).
    Incompatible(String),
    /// A secondary policy stored no trajectory, so the batch would teach nothing of its
    /// behaviour.
    NoTrajectories {
        /// The behaviour.
        behaviour: &'static str,
        /// Its stored trajectories, empty.
        path: PathBuf,
    },
    /// A labels file holds labels made with other settings than asked for.
    LabelsDiffer {
        /// The labels file.
        path: PathBuf,
        /// The header field that differs.
        field: &'static str,
        /// Its value in the file.
        in_file: String,
        /// The value asked for.
        requested: String,
    },
    /// A labelling or planning thread panicked on a state (a planner bug, say); what was
    /// written before stays.
    Panicked {
        /// The work: `labelling` or `planning`.
        work: &'static str,
        /// The first state of the work that panicked.
        first: u64,
        /// Its last state (`first` for one state).
        last: u64,
    },
    /// plotters could not draw a plot or write its image (its message, naming the file where
    /// there is one).
    Plot(String),
    /// A font file given for a plot is not a usable TTF font.
    Font {
        /// The file.
        path: PathBuf,
    },
    /// A curve argument of a plot is neither `DIR` nor `LABEL=DIR[,DIR...]`.
    Curve {
        /// The argument.
        text: String,
    },
    /// A planner results file is not the output of `wheelleg plan --json`.
    NotPlanResults(serde_json::Error),
    /// A planner results file names a scenario twice.
    ScenarioTwice {
        /// The scenario.
        name: String,
    },
    /// The planner results name no result for a scenario evaluated.
    NoPlanResult {
        /// The scenario.
        name: String,
    },
    /// An error, with what to do about it.
    Hint {
        /// What went wrong.
        error: Box<TrainError>,
        /// What to do (the command to run first, say).
        hint: &'static str,
    },
    /// An error during one stage of the work.
    Stage {
        /// The stage, as the message names it.
        stage: String,
        /// What went wrong in it.
        error: Box<TrainError>,
    },
    /// An error about the file `path`.
    In {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        error: Box<TrainError>,
    },
}

impl TrainError {
    /// `action` on `path` failed with `error`.
    pub fn io(path: impl Into<PathBuf>, action: &'static str, error: std::io::Error) -> Self {
        TrainError::Io {
            path: path.into(),
            action,
            error,
        }
    }

    /// `error`, about the file `path`; as it is when its message names a file already.
    pub fn in_file(path: impl Into<PathBuf>, error: impl Into<TrainError>) -> Self {
        match error.into() {
            named @ (TrainError::Io { .. }
            | TrainError::In { .. }
            | TrainError::BatchFile(BatchFileError::Io { .. })
            | TrainError::Checkpoint(
                CheckpointError::Io { .. } | CheckpointError::In { .. },
            )) => named,
            error => TrainError::In {
                path: path.into(),
                error: Box::new(error),
            },
        }
    }

    /// `error`, during `stage`.
    pub fn stage(stage: impl Into<String>, error: impl Into<TrainError>) -> Self {
        TrainError::Stage {
            stage: stage.into(),
            error: Box::new(error.into()),
        }
    }

    /// `error`, followed by `hint`.
    pub fn hint(error: impl Into<TrainError>, hint: &'static str) -> Self {
        TrainError::Hint {
            error: Box::new(error.into()),
            hint,
        }
    }

    /// A config key or option whose value cannot be used.
    pub fn setting(key: &'static str, problem: impl Into<String>) -> Self {
        TrainError::Setting {
            key,
            problem: problem.into(),
        }
    }
}

impl fmt::Display for TrainError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TrainError::Config(e) => write!(f, "{e}"),
            TrainError::Checkpoint(e) => write!(f, "{e}"),
            TrainError::BatchFile(e) => write!(f, "{e}"),
            TrainError::Replay(e) => write!(f, "{e}"),
            TrainError::VecEnv(e) => write!(f, "{e}"),
            TrainError::Quantize(e) => write!(f, "{e}"),
            TrainError::Scenario(e) => write!(f, "{e}"),
            TrainError::Stack(message)
            | TrainError::Shape(message)
            | TrainError::Incompatible(message)
            | TrainError::Plot(message) => f.write_str(message),
            TrainError::Refused(e) => write!(f, "the runtime refuses the exported weights: {e}"),
            TrainError::Infer(e) => write!(f, "int8 policy: {e}"),
            TrainError::Io {
                path,
                action,
                error,
            } => write!(f, "cannot {action} {}: {error}", path.display()),
            TrainError::Metrics {
                path,
                line: Some(line),
                error,
            } => write!(f, "{} line {line}: {error}", path.display()),
            TrainError::Metrics {
                path,
                line: None,
                error,
            } => write!(f, "cannot encode a line of {}: {error}", path.display()),
            TrainError::BackendNotBuilt { backend } => {
                write!(f, "backend {backend} needs the cargo feature `{backend}`")
            }
            TrainError::Diverged {
                policy_loss,
                value_loss,
            } => write!(
                f,
                "loss became non-finite (policy {policy_loss}, value {value_loss}): lower \
                 ppo.learning_rate"
            ),
            TrainError::QatDiverged { step } => write!(
                f,
                "QAT loss became non-finite at step {step}: lower the QAT learning rate"
            ),
            TrainError::BatchTooSmall { samples } => {
                write!(f, "batch of {samples} samples is too small for an update")
            }
            TrainError::NoTrajectory { index } => {
                write!(f, "trajectory batch has no trajectory {index}")
            }
            TrainError::Setting { key, problem } => write!(f, "{key}: {problem}"),
            TrainError::Nothing { what } => write!(f, "no {what}"),
            TrainError::RunExists { out } => write!(
                f,
                "{} already holds a run; pass --resume to continue it or choose another --out",
                out.display()
            ),
            TrainError::ConfigChanged {
                checkpoint,
                changes,
                config,
            } => write!(
                f,
                "{} was written with a different config ({}); resume with the run's own {}",
                checkpoint.display(),
                changes.join(", "),
                config.display()
            ),
            TrainError::SeedChanged {
                checkpoint,
                stored,
                requested,
            } => write!(
                f,
                "{} belongs to seed {stored}, not {requested}",
                checkpoint.display()
            ),
            TrainError::NoStartStage { checkpoint } => write!(
                f,
                "{} holds no start-stage state but the config has run.start_stage < 1",
                checkpoint.display()
            ),
            TrainError::StartStageMismatch { stage, entries } => write!(
                f,
                "checkpoint start stage {stage} with {entries} window entries does not fit this \
                 run"
            ),
            TrainError::NetworkMismatch {
                path,
                conv_channels,
                hidden,
                config_conv_channels,
                config_hidden,
            } => write!(
                f,
                "{}: its network (conv channels {conv_channels:?}, hidden {hidden:?}) is not the \
                 config's [network] (conv channels {config_conv_channels:?}, hidden \
                 {config_hidden:?})",
                path.display()
            ),
            TrainError::BatchRobot {
                what,
                batch_robot,
                run_robot,
                part,
            } => write!(
                f,
                "{what} holds trajectories of robot '{batch_robot}', and this run trains robot \
                 '{run_robot}' (the {part} differs): replay only a robot's own trajectories"
            ),
            TrainError::NoTrajectories { behaviour, path } => write!(
                f,
                "secondary {behaviour} stored no successful, collision-free episode of the task \
                 as specified ({} is empty; with a start-stage curriculum, its start stage never \
                 reached 1): give it more env steps \
                 (curriculum.secondary_env_steps_by_behaviour.{behaviour}) and resume with \
                 `wheelleg train secondary --resume`",
                path.display()
            ),
            TrainError::LabelsDiffer {
                path,
                field,
                in_file,
                requested,
            } => write!(
                f,
                "{} holds labels made with {field} = {in_file}, requested {requested} (another \
                 policy, stack, scene set or planner setting): delete it or choose another --out",
                path.display()
            ),
            TrainError::Panicked { work, first, last } if first == last => {
                write!(f, "a {work} thread panicked at state {first}")
            }
            TrainError::Panicked { work, first, last } => {
                write!(f, "a {work} thread panicked at states {first} to {last}")
            }
            TrainError::Font { path } => {
                write!(f, "{} is not a usable TTF font", path.display())
            }
            TrainError::Curve { text } => write!(
                f,
                "{text:?}: a curve is DIR or LABEL=DIR[,DIR...] with a label and a folder"
            ),
            TrainError::NotPlanResults(e) => {
                write!(f, "not the output of `wheelleg plan --json`: {e}")
            }
            TrainError::ScenarioTwice { name } => write!(f, "scenario {name:?} appears twice"),
            TrainError::NoPlanResult { name } => {
                write!(f, "the planner results name no scenario {name:?}")
            }
            TrainError::Hint { error, hint } => write!(f, "{error} ({hint})"),
            TrainError::Stage { stage, error } => write!(f, "{stage}: {error}"),
            TrainError::In { path, error } => write!(f, "{}: {error}", path.display()),
        }
    }
}

impl std::error::Error for TrainError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            TrainError::Config(e) => Some(e),
            TrainError::Checkpoint(e) => Some(e),
            TrainError::BatchFile(e) => Some(e),
            TrainError::Replay(e) => Some(e),
            TrainError::VecEnv(e) => Some(e),
            TrainError::Quantize(e) => Some(e),
            TrainError::Scenario(e) => Some(e),
            TrainError::Io { error, .. } => Some(error),
            TrainError::Metrics { error, .. } | TrainError::NotPlanResults(error) => Some(error),
            TrainError::Hint { error, .. }
            | TrainError::Stage { error, .. }
            | TrainError::In { error, .. } => Some(error.as_ref()),
            _ => None,
        }
    }
}

impl From<ConfigError> for TrainError {
    fn from(e: ConfigError) -> Self {
        TrainError::Config(e)
    }
}

impl From<CheckpointError> for TrainError {
    fn from(e: CheckpointError) -> Self {
        TrainError::Checkpoint(e)
    }
}

impl From<BatchFileError> for TrainError {
    fn from(e: BatchFileError) -> Self {
        TrainError::BatchFile(e)
    }
}

impl From<ReplayError> for TrainError {
    fn from(e: ReplayError) -> Self {
        TrainError::Replay(e)
    }
}

impl From<VecEnvError> for TrainError {
    fn from(e: VecEnvError) -> Self {
        TrainError::VecEnv(e)
    }
}

impl From<QuantizeError> for TrainError {
    fn from(e: QuantizeError) -> Self {
        TrainError::Quantize(e)
    }
}

impl From<ScenarioError> for TrainError {
    fn from(e: ScenarioError) -> Self {
        TrainError::Scenario(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::error::Error;

    #[test]
    fn context_wraps_keep_the_inner_message_and_chain_to_it() {
        let inner = TrainError::setting("run.exit_behaviour", "no fence named \"gate\"");
        let wrapped = TrainError::hint(
            TrainError::stage("primary", inner),
            "check the config first",
        );
        assert_eq!(
            wrapped.to_string(),
            "primary: run.exit_behaviour: no fence named \"gate\" (check the config first)"
        );
        let stage = wrapped.source().map(ToString::to_string);
        assert_eq!(
            stage.as_deref(),
            Some("primary: run.exit_behaviour: no fence named \"gate\"")
        );
    }

    #[test]
    fn a_file_is_named_once() {
        let missing = std::io::Error::new(std::io::ErrorKind::NotFound, "gone");
        let io = TrainError::io("runs/a/metrics.jsonl", "read", missing);
        let named = TrainError::in_file("runs/a", io);
        assert!(matches!(named, TrainError::Io { .. }), "{named}");
        assert_eq!(named.to_string(), "cannot read runs/a/metrics.jsonl: gone");
        let unnamed =
            TrainError::in_file("runs/a/batch.wltb", TrainError::NoTrajectory { index: 3 });
        assert_eq!(
            unnamed.to_string(),
            "runs/a/batch.wltb: trajectory batch has no trajectory 3"
        );
    }

    #[test]
    fn divergence_says_what_to_lower() {
        let e = TrainError::Diverged {
            policy_loss: f32::NAN,
            value_loss: 1.5,
        };
        assert_eq!(
            e.to_string(),
            "loss became non-finite (policy NaN, value 1.5): lower ppo.learning_rate"
        );
    }
}
