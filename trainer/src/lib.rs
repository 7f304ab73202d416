//! Training side of the wheel-legged robot's navigation policy.
//!
//! PPO on the simulator (paper: "Preliminaries", "Network Architecture", "Evaluation"), then the
//! path from the float network to the bytes the robot runs. Read in this order:
//!
//! - [`config`]: every hyperparameter, from a TOML file.
//! - [`network`]: the actor-critic CNN as a burn graph over the [`network_f32`] parameters.
//! - [`vec_env`]: many simulator episodes stepped in lock-step over the cores.
//! - [`storage`]: the rollout and its advantages (GAE).
//! - [`ppo`]: the clipped surrogate, value loss, entropy bonus, Adam update.
//! - [`runner`]: the training loop (rollout, advantages, update, metrics, checkpoints).
//! - [`checkpoint`]: atomic, validated checkpoints for exact resumes.
//! - [`evaluate`]: success, collision-free success and path length against the planner.
//! - [`plot`]: learning curves of runs.
//! - [`network_f32`]: the policy network in plain f32 and its forward pass, the float
//!   reference every int8 result is compared with.
//! - [`quantize`]: post-training int8 quantization and the `.wlw` weights file bytes.
//! - [`export`]: writing a weights file atomically.

pub mod checkpoint;
pub mod config;
pub mod evaluate;
pub mod export;
pub mod network;
pub mod network_f32;
pub mod plot;
pub mod ppo;
pub mod quantize;
pub mod runner;
pub mod storage;
pub mod vec_env;
