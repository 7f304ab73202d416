//! Checkpoints: everything a run needs to continue exactly where it stopped, written atomically
//! and validated on load.
//!
//! File layout: `WLCKPT01` magic (8 bytes), payload length (u64 LE), FNV-1a 64 checksum of the
//! payload (u64 LE), then the postcard-encoded [`Checkpoint`], optionally followed (inside the
//! same payload and checksum) by a postcard-encoded [`CheckpointExtras`]. A truncated, corrupt
//! or foreign file is refused with a message saying which check failed.
//!
//! The extras are state that only some runs have (the start-stage curriculum's). They are
//! written only when not empty, so every other checkpoint is byte for byte what it was before
//! they existed, and checkpoints written before still load (no extras: nothing to restore);
//! a reader that knows no extras ([`Checkpoint::from_bytes`]) ignores them.

use crate::network_f32::{Architecture, Conv2dF32, ConvSpec, DenseF32, NetworkF32};
use crate::ppo::Adam;
use crate::vec_env::EnvSnapshot;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};
use wheelleg_robot::RobotDescription;

const MAGIC: &[u8; 8] = b"WLCKPT01";
const HEADER_LEN: usize = 24;

/// Why a checkpoint cannot be read, used or written.
#[derive(Debug)]
pub enum CheckpointError {
    /// The file could not be read (or, `writing`, written).
    Io {
        /// The file.
        path: PathBuf,
        /// Whether it was being written.
        writing: bool,
        /// What the system said.
        error: std::io::Error,
    },
    /// Not a wheelleg checkpoint: shorter than its header, or another magic.
    NotACheckpoint,
    /// The payload is not as long as the header says.
    Truncated {
        /// Bytes after the header.
        payload_bytes: usize,
        /// Bytes the header announces.
        header_bytes: usize,
    },
    /// The payload's checksum does not match the header's.
    Checksum,
    /// A record does not decode, or bytes follow the last one.
    Corrupt(String),
    /// The network's architecture is impossible, or its tensors do not fit it.
    Network(String),
    /// The optimizer state does not match the network.
    Optimizer,
    /// The record could not be encoded.
    Encode(String),
    /// Trained for another robot (both named), or the robot recorded does not read.
    Robot(String),
    /// One of the above, in the file `path`.
    In {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        error: Box<CheckpointError>,
    },
}

impl fmt::Display for CheckpointError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CheckpointError::Io {
                path,
                writing,
                error,
            } => {
                let verb = if *writing { "write" } else { "read" };
                write!(f, "cannot {verb} checkpoint {}: {error}", path.display())
            }
            CheckpointError::NotACheckpoint => f.write_str("not a wheelleg checkpoint (bad magic)"),
            CheckpointError::Truncated {
                payload_bytes,
                header_bytes,
            } => write!(
                f,
                "checkpoint truncated or padded: payload is {payload_bytes} bytes, header says \
                 {header_bytes}"
            ),
            CheckpointError::Checksum => f.write_str("checkpoint corrupt: checksum mismatch"),
            CheckpointError::Corrupt(what) => write!(f, "checkpoint corrupt: {what}"),
            CheckpointError::Network(what) => f.write_str(what),
            CheckpointError::Optimizer => {
                f.write_str("checkpoint optimizer state does not match its network")
            }
            CheckpointError::Encode(what) => write!(f, "cannot encode checkpoint: {what}"),
            CheckpointError::Robot(what) => f.write_str(what),
            CheckpointError::In { path, error } => write!(f, "{}: {error}", path.display()),
        }
    }
}

impl std::error::Error for CheckpointError {}

/// The architecture as stored (network_f32's types stay serde-free for the no_std side).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArchRecord {
    /// Height-map rows and columns.
    pub height: (usize, usize),
    /// State features.
    pub state_len: usize,
    /// Conv layers: (in, out, kernel, stride, padding).
    pub convs: Vec<(usize, usize, usize, usize, usize)>,
    /// Hidden dense widths.
    pub hidden: Vec<usize>,
    /// Value head present.
    pub value_head: bool,
}

impl ArchRecord {
    /// Records an architecture.
    pub fn from_arch(a: &Architecture) -> Self {
        ArchRecord {
            height: (a.height_rows, a.height_cols),
            state_len: a.state_len,
            convs: a
                .convs
                .iter()
                .map(|c| (c.in_channels, c.out_channels, c.kernel, c.stride, c.padding))
                .collect(),
            hidden: a.hidden.clone(),
            value_head: a.value_head,
        }
    }

    /// The architecture.
    pub fn to_arch(&self) -> Architecture {
        Architecture {
            height_rows: self.height.0,
            height_cols: self.height.1,
            state_len: self.state_len,
            convs: self
                .convs
                .iter()
                .map(
                    |&(in_channels, out_channels, kernel, stride, padding)| ConvSpec {
                        in_channels,
                        out_channels,
                        kernel,
                        stride,
                        padding,
                    },
                )
                .collect(),
            hidden: self.hidden.clone(),
            value_head: self.value_head,
        }
    }
}

/// A network: architecture plus parameter tensors in `network::parameters` order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NetworkRecord {
    /// Shape.
    pub arch: ArchRecord,
    /// Tensors.
    pub tensors: Vec<Vec<f32>>,
}

impl NetworkRecord {
    /// Records a network.
    pub fn from_network(net: &NetworkF32) -> Self {
        NetworkRecord {
            arch: ArchRecord::from_arch(&net.arch),
            tensors: crate::network::parameters(net)
                .into_iter()
                .map(<[f32]>::to_vec)
                .collect(),
        }
    }

    /// Rebuilds the network, checking every tensor's length against the architecture.
    pub fn to_network(&self) -> Result<NetworkF32, CheckpointError> {
        check_shape(&self.arch)?;
        let arch = self.arch.to_arch();
        let mut t = self.tensors.iter();
        let mut take = |len: usize, what: &str| -> Result<Vec<f32>, CheckpointError> {
            let v = t.next().ok_or_else(|| {
                CheckpointError::Network(format!("checkpoint network is missing tensor {what}"))
            })?;
            if v.len() != len {
                return Err(CheckpointError::Network(format!(
                    "checkpoint tensor {what} has {} values, the architecture needs {len}",
                    v.len()
                )));
            }
            Ok(v.clone())
        };
        let mut convs = Vec::new();
        for (i, &spec) in arch.convs.iter().enumerate() {
            let weights = take(
                spec.out_channels * spec.in_channels * spec.kernel * spec.kernel,
                &format!("conv{i}.weight"),
            )?;
            let bias = take(spec.out_channels, &format!("conv{i}.bias"))?;
            convs.push(Conv2dF32 {
                spec,
                weights,
                bias,
            });
        }
        let mut width = arch.concat_len();
        let mut dense =
            |out: usize, name: &str, width: usize| -> Result<DenseF32, CheckpointError> {
                Ok(DenseF32 {
                    in_features: width,
                    out_features: out,
                    weights: take(out * width, &format!("{name}.weight"))?,
                    bias: take(out, &format!("{name}.bias"))?,
                })
            };
        let mut hidden = Vec::new();
        for (i, &out) in arch.hidden.iter().enumerate() {
            hidden.push(dense(out, &format!("hidden{i}"), width)?);
            width = out;
        }
        let action_head = dense(crate::network_f32::ACTION_LOGITS, "action_head", width)?;
        let value_head = if arch.value_head {
            Some(dense(1, "value_head", width)?)
        } else {
            None
        };
        if t.next().is_some() {
            return Err(CheckpointError::Network(
                "checkpoint network has more tensors than its architecture".into(),
            ));
        }
        Ok(NetworkF32 {
            arch,
            convs,
            hidden,
            action_head,
            value_head,
        })
    }
}

/// Checks that every size the architecture implies is computable: no zero stride or kernel, no
/// kernel larger than its padded input, channels that chain, and no product that overflows.
/// A checkpoint is outside data once it is on disk; the fuzz target `checkpoint_payload` found
/// an architecture whose feature count overflowed (docs/robustness.md).
fn check_shape(arch: &ArchRecord) -> Result<(), CheckpointError> {
    let bad = |what: String| {
        Err(CheckpointError::Network(format!(
            "checkpoint architecture is impossible: {what}"
        )))
    };
    let (mut h, mut w, mut c) = (arch.height.0, arch.height.1, 1usize);
    for (i, &(in_channels, out_channels, kernel, stride, padding)) in arch.convs.iter().enumerate()
    {
        let padded = |side: usize| padding.checked_mul(2).and_then(|p| side.checked_add(p));
        let (Some(ph), Some(pw)) = (padded(h), padded(w)) else {
            return bad(format!("conv{i} padding"));
        };
        if in_channels != c || stride == 0 || kernel == 0 || kernel > ph || kernel > pw {
            return bad(format!("conv{i} channels, kernel, stride or padding"));
        }
        let weights = out_channels
            .checked_mul(in_channels)
            .and_then(|x| x.checked_mul(kernel))
            .and_then(|x| x.checked_mul(kernel));
        if weights.is_none() {
            return bad(format!("conv{i} size"));
        }
        (h, w, c) = (
            (ph - kernel) / stride + 1,
            (pw - kernel) / stride + 1,
            out_channels,
        );
    }
    let Some(mut width) = h
        .checked_mul(w)
        .and_then(|x| x.checked_mul(c))
        .and_then(|x| x.checked_add(arch.state_len))
    else {
        return bad("feature count".into());
    };
    for &out in &arch.hidden {
        if out.checked_mul(width).is_none() {
            return bad("dense layer size".into());
        }
        width = out;
    }
    if crate::network_f32::ACTION_LOGITS
        .checked_mul(width)
        .is_none()
    {
        return bad("head size".into());
    }
    Ok(())
}

/// Sums of the current iteration are not stored: checkpoints are taken between iterations.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    /// What produced it (`baseline`, `secondary-straight`, ...).
    pub kind: String,
    /// The run's config as TOML; a resume with a different config is refused.
    pub config_toml: String,
    /// The run's seed.
    pub seed: u64,
    /// Iterations completed.
    pub iteration: u64,
    /// Environment steps taken.
    pub env_steps: u64,
    /// The policy.
    pub network: NetworkRecord,
    /// Optimizer state.
    pub adam: Adam,
    /// Word position of the sampling RNG (actions, minibatch shuffles).
    pub sampler_word_pos: u128,
    /// The environments.
    pub envs: Vec<EnvSnapshot>,
    /// Seconds of training before this checkpoint (so steps/s and ETA survive a resume).
    pub elapsed_s: f64,
}

/// Run state stored after the [`Checkpoint`] record (see the module documentation).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CheckpointExtras {
    /// The start-stage curriculum's state, when the run uses it.
    pub start_stage: Option<StartStageState>,
    /// Each environment's remembered failed scenes (scenario-file JSON), when the run
    /// re-samples them (`run.failure_resample_probability`). Extras written before this field
    /// existed end after `start_stage`; they still load (see [`Checkpoint::from_bytes`]).
    pub failures: Option<Vec<String>>,
    /// The robot trained for, as its description's TOML; `None` for the shipped robot (so a
    /// shipped robot's checkpoint is byte for byte what it was before robots were named).
    pub robot: Option<String>,
}

/// The extras as written before `failures` existed.
#[derive(Deserialize)]
struct ExtrasBeforeFailures {
    start_stage: Option<StartStageState>,
}

/// The extras as written before `robot` existed.
#[derive(Deserialize)]
struct ExtrasBeforeRobot {
    start_stage: Option<StartStageState>,
    failures: Option<Vec<String>>,
}

impl CheckpointExtras {
    /// How `robot` is recorded: `None` for the shipped robot, its description otherwise.
    pub fn robot_record(robot: &RobotDescription) -> Option<String> {
        (*robot != RobotDescription::shipped()).then(|| robot.to_toml())
    }

    /// The robot the checkpoint's policy was trained for.
    pub fn robot(&self) -> Result<RobotDescription, CheckpointError> {
        match &self.robot {
            None => Ok(RobotDescription::shipped()),
            Some(text) => RobotDescription::from_toml(text).map_err(|e| {
                CheckpointError::Robot(format!("checkpoint corrupt: its robot description: {e}"))
            }),
        }
    }

    /// Refuses a checkpoint (`what`) trained for another robot than `robot`, naming both.
    pub fn check_robot(&self, robot: &RobotDescription, what: &str) -> Result<(), CheckpointError> {
        let trained = self.robot()?;
        robot
            .accepts(&trained.trained_for(), what)
            .map_err(CheckpointError::Robot)
    }
}

/// Where a run's start-stage curriculum stands (`run.start_stage`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StartStageState {
    /// Stage of the scenes drawn from now on.
    pub stage: f32,
    /// (successes, episodes) at that stage of each iteration since it was reached, oldest
    /// first, at most `run.start_stage_window` of them.
    pub window: Vec<(u32, u32)>,
    /// Stage each environment's current scene was drawn at, in environment order.
    pub env_stages: Vec<f32>,
}

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

impl Checkpoint {
    /// Encodes the file bytes.
    pub fn to_bytes(&self) -> Result<Vec<u8>, CheckpointError> {
        self.to_bytes_with(&CheckpointExtras::default())
    }

    /// Encodes the file bytes with `extras` after the record (nothing when they are empty).
    pub fn to_bytes_with(&self, extras: &CheckpointExtras) -> Result<Vec<u8>, CheckpointError> {
        let mut payload =
            postcard::to_allocvec(self).map_err(|e| CheckpointError::Encode(e.to_string()))?;
        if *extras != CheckpointExtras::default() {
            payload.extend(
                postcard::to_allocvec(extras)
                    .map_err(|e| CheckpointError::Encode(format!("extras: {e}")))?,
            );
        }
        let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        out.extend_from_slice(&fnv1a(&payload).to_le_bytes());
        out.extend_from_slice(&payload);
        Ok(out)
    }

    /// Decodes and validates file bytes (ignoring any extras).
    pub fn from_bytes(bytes: &[u8]) -> Result<Checkpoint, CheckpointError> {
        Checkpoint::from_bytes_with_extras(bytes).map(|(c, _)| c)
    }

    /// Decodes and validates file bytes and the extras after the record (empty when there are
    /// none).
    pub fn from_bytes_with_extras(
        bytes: &[u8],
    ) -> Result<(Checkpoint, CheckpointExtras), CheckpointError> {
        if bytes.len() < HEADER_LEN || &bytes[..8] != MAGIC {
            return Err(CheckpointError::NotACheckpoint);
        }
        let len = u64::from_le_bytes(bytes[8..16].try_into().unwrap_or_default()) as usize;
        let sum = u64::from_le_bytes(bytes[16..24].try_into().unwrap_or_default());
        let payload = &bytes[HEADER_LEN..];
        if payload.len() != len {
            return Err(CheckpointError::Truncated {
                payload_bytes: payload.len(),
                header_bytes: len,
            });
        }
        if fnv1a(payload) != sum {
            return Err(CheckpointError::Checksum);
        }
        let (c, rest): (Checkpoint, &[u8]) = postcard::take_from_bytes(payload)
            .map_err(|e| CheckpointError::Corrupt(e.to_string()))?;
        let extras = if rest.is_empty() {
            CheckpointExtras::default()
        } else {
            let (extras, tail): (CheckpointExtras, &[u8]) = postcard::take_from_bytes(rest)
                .or_else(|e| {
                    // postcard records carry no field names: an older record is one that
                    // decodes in the older shape and leaves nothing behind.
                    match postcard::take_from_bytes::<ExtrasBeforeRobot>(rest) {
                        Ok((old, [])) => Ok((
                            CheckpointExtras {
                                start_stage: old.start_stage,
                                failures: old.failures,
                                robot: None,
                            },
                            &[][..],
                        )),
                        _ => match postcard::take_from_bytes::<ExtrasBeforeFailures>(rest) {
                            Ok((old, [])) => Ok((
                                CheckpointExtras {
                                    start_stage: old.start_stage,
                                    failures: None,
                                    robot: None,
                                },
                                &[][..],
                            )),
                            _ => Err(e),
                        },
                    }
                })
                .map_err(|e| CheckpointError::Corrupt(format!("extras: {e}")))?;
            if !tail.is_empty() {
                return Err(CheckpointError::Corrupt(format!(
                    "{} bytes after the extras",
                    tail.len()
                )));
            }
            extras
        };
        let net = c.network.to_network()?;
        if !c.adam.fits(&net) {
            return Err(CheckpointError::Optimizer);
        }
        Ok((c, extras))
    }

    /// Writes the checkpoint atomically (temporary file + rename).
    pub fn save(&self, path: &Path) -> Result<(), CheckpointError> {
        self.save_with(path, &CheckpointExtras::default())
    }

    /// [`Checkpoint::save`] with `extras`.
    pub fn save_with(&self, path: &Path, extras: &CheckpointExtras) -> Result<(), CheckpointError> {
        let bytes = self.to_bytes_with(extras)?;
        wheelleg_sim::atomic_write(path, &bytes).map_err(|error| CheckpointError::Io {
            path: path.to_path_buf(),
            writing: true,
            error,
        })
    }

    /// Reads and validates a checkpoint file.
    pub fn load(path: &Path) -> Result<Checkpoint, CheckpointError> {
        Checkpoint::load_with_extras(path).map(|(c, _)| c)
    }

    /// Reads and validates a checkpoint file and its extras.
    pub fn load_with_extras(
        path: &Path,
    ) -> Result<(Checkpoint, CheckpointExtras), CheckpointError> {
        let bytes = std::fs::read(path).map_err(|error| CheckpointError::Io {
            path: path.to_path_buf(),
            writing: false,
            error,
        })?;
        Checkpoint::from_bytes_with_extras(&bytes).map_err(|error| CheckpointError::In {
            path: path.to_path_buf(),
            error: Box::new(error),
        })
    }
}

/// Loads just the policy from a checkpoint file.
pub fn load_policy(path: &Path) -> Result<NetworkF32, CheckpointError> {
    Checkpoint::load(path)?.network.to_network()
}

/// Refuses the checkpoint at `path` when it was trained for another robot than `robot`,
/// naming both.
pub fn check_robot(path: &Path, robot: &RobotDescription) -> Result<(), CheckpointError> {
    let (_, extras) = Checkpoint::load_with_extras(path)?;
    extras.check_robot(robot, &path.display().to_string())
}

#[cfg(test)]
mod tests;
