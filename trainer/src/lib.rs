//! Training side of the wheel-legged robot's navigation policy.
//!
//! PPO on the simulator (paper: "Preliminaries", "Network Architecture", "Evaluation"), then the
//! path from the float network to the bytes the robot runs. Read in this order:
//!
//! - [`config`]: every hyperparameter, from a TOML file.
//! - [`error`]: why a run, evaluation, export or plot stopped ([`TrainError`]).
//! - [`network`]: the actor-critic CNN as a burn graph over the [`network_f32`] parameters.
//! - [`conv_kernel`]: the conv stack's specialised training kernel (im2col + GEMM).
//! - [`vec_env`]: many simulator episodes stepped in lock-step over the cores.
//! - [`storage`]: the rollout and its advantages (GAE).
//! - [`ppo`]: the clipped surrogate, value loss, entropy bonus, Adam update.
//! - [`replay`]: Algorithm 2's replayed samples, advantages from the current critic.
//! - [`runner`]: the training loop (rollout, advantages, update, metrics, checkpoints).
//! - [`curriculum`]: the paper's Algorithms 1 and 2 stage by stage (secondary policies,
//!   trajectory batch, primary policy).
//! - [`checkpoint`]: atomic, validated checkpoints for exact resumes.
//! - [`batch_policy`]: the float network behind the decision stack's batched policy interface.
//! - [`evaluate`]: success, collision-free success and path length against the planner.
//! - [`plot`]: learning curves of runs.
//! - [`network_f32`]: the policy network in plain f32 and its forward pass, the float
//!   reference every int8 result is compared with.
//! - [`quantize`]: post-training int8 quantization and the `.wlw` weights file bytes.
//! - [`export`]: writing a weights file atomically.
//! - [`trajectory`]: stored trajectories, the domain-randomized trajectory batch and its file,
//!   and the obstacle relevance test.

pub mod batch_policy;
pub mod checkpoint;
pub mod config;
pub mod conv_kernel;
pub mod curriculum;
pub mod error;
pub mod evaluate;
pub mod export;
pub mod network;
pub mod network_f32;
pub mod plot;
pub mod ppo;
pub mod quantize;
pub mod replay;
pub mod runner;
pub mod storage;
pub mod trajectory;
pub mod vec_env;

pub use error::TrainError;
