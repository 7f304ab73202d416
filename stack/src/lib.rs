//! What the robot does between the policy's logits and the action it sends, on the host.
//!
//! The layers, each behind one small interface, in the order an action passes them:
//! - [`policy`]: a policy evaluated on a batch of observations, float or int8
//!   ([`policy::BatchPolicy`]); the int8 network is the robot's own runtime.
//! - [`rule`]: the decision rule (the most probable action not yet taken at this observation,
//!   `wheelleg_runtime::decision`), the collision guard on a height map
//!   (`wheelleg_runtime::guard`) and the arrival rule (`wheelleg_runtime::arrival`): what the
//!   controller firmware runs.
//! - [`lookahead`]: rollouts of the policy on the robot's own map, and the exact search for a
//!   shorter way: what a companion computer adds.
//! - the search for the last metres (`wheelleg_sim::local_plan`), switched on by
//!   [`StackConfig::last_metres`].
//!
//! [`StackConfig`] names which layers run; [`Preset`] names the three stacks users ask for:
//! `policy` (the rule alone), `robot` (what the controller firmware runs) and `full` (`robot`
//! plus the look-ahead and the searches). [`episodes::run_episodes`] drives a batch of
//! scenarios to their end through a stack, as `wheelleg eval` measures it; the closed loop's
//! policy driver decides one step at a time through the same [`rule`] and [`lookahead`].

pub mod config;
pub mod episodes;
pub mod lookahead;
pub mod policy;
pub mod rule;

pub use config::{DecisionRule, GuardLayer, Preset, StackConfig};
