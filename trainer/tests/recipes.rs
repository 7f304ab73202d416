//! The recipes users run (configs/shipped.toml and its exit stage configs/shipped-exit.toml,
//! configs/baseline.toml, configs/dagger.toml, configs/smoke.toml) are self-contained: no
//! `extends`, every key written out, and each resolves to exactly the config recorded here
//! (`TrainConfig::to_toml` of the file as loaded). A change to a recipe, or to a default a recipe
//! relies on, shows up here as a difference to review. The exit stage and a round of expert
//! iteration are the shipped recipe with the keys they change, and nothing else.
//!
//! Run: `cargo test --release -p wheelleg-trainer --test recipes`.

use std::path::{Path, PathBuf};
use wheelleg_trainer::config::TrainConfig;

/// configs/shipped.toml as loaded.
const SHIPPED: &str = r#"[run]
scene_kind = "complex"
steps_per_iteration = 10000
num_envs = 50
total_env_steps = 30000000
max_episode_steps = 100
invalid_reward = -0.1
checkpoint_interval = 5
threads = 2
backend = "flex"
start_yaw_within_deg = 180.0
start_stage = 1.0
start_stage_step = 0.1
start_stage_success_rate = 0.5
start_stage_window = 3
failure_resample_probability = 0.0
failure_memory_per_env = 8
composed_share = 0.5
exit_share = 0.0
exit_behaviour = "squeeze"
composed_from_env_steps = 10000000
stop_success_rate = 0.0
stop_window = 10
robot = ""

[ppo]
learning_rate = 0.001
learning_rate_final = 0.0
anneal_start_env_steps = 26000000
adam_epsilon = 0.00001
gamma = 0.97
gae_lambda = 0.9
clip_epsilon = 0.2
policy_coef = 1.0
value_coef = 0.5
entropy_coef = 0.003
epochs = 4
minibatch_size = 256
max_grad_norm = 0.5
normalize_advantages = true
target_kl = 0.05
conv_kernel = "native"

[network]
conv_channels = [16, 32, 32]
hidden = [128]

[curriculum]
behaviours = ["straight", "around", "lift", "spread", "squeeze"]
secondary_steps_per_iteration = 3000
secondary_env_steps = 500000
keep_trajectories = 1000
randomizations = 200
replay_steps_per_iteration = 2000
replay_imitation_coef = 0.5
replay_balance = "behaviour"
label_steps_per_iteration = 2000
label_imitation_coef = 0.5
primary_init = "scratch"
secondary_init_temperature = 10.0
secondary_entropy_coef = 0.01
secondary_start_yaw_within_deg = 180.0
start_stage_behaviours = ["spread", "squeeze"]
start_stage_initial = 0.0
start_stage_step = 0.1
start_stage_success_rate = 0.5
start_stage_window = 3
secondary_stop_success_rate = 0.0
secondary_stop_window = 10

[curriculum.secondary_env_steps_by_behaviour]
lift = 1500000
squeeze = 2500000
"#;

/// configs/baseline.toml as loaded.
const BASELINE: &str = r#"[run]
scene_kind = "complex"
steps_per_iteration = 10000
num_envs = 50
total_env_steps = 5000000
max_episode_steps = 100
invalid_reward = -0.1
checkpoint_interval = 5
threads = 2
backend = "flex"
start_yaw_within_deg = 180.0
start_stage = 1.0
start_stage_step = 0.1
start_stage_success_rate = 0.5
start_stage_window = 3
failure_resample_probability = 0.0
failure_memory_per_env = 8
composed_share = 0.0
exit_share = 0.0
exit_behaviour = "squeeze"
composed_from_env_steps = 0
stop_success_rate = 0.0
stop_window = 10
robot = ""

[ppo]
learning_rate = 0.001
anneal_start_env_steps = 0
adam_epsilon = 0.00001
gamma = 0.97
gae_lambda = 0.9
clip_epsilon = 0.2
policy_coef = 1.0
value_coef = 0.5
entropy_coef = 0.003
epochs = 4
minibatch_size = 256
max_grad_norm = 0.5
normalize_advantages = true
target_kl = 0.05
conv_kernel = "native"

[network]
conv_channels = [16, 32, 32]
hidden = [128]

[curriculum]
behaviours = ["straight", "around", "lift", "spread", "squeeze"]
secondary_steps_per_iteration = 3000
secondary_env_steps = 500000
keep_trajectories = 1000
randomizations = 200
replay_steps_per_iteration = 2000
replay_imitation_coef = 0.0
replay_balance = "trajectory"
label_steps_per_iteration = 2000
label_imitation_coef = 0.5
primary_init = "scratch"
secondary_init_temperature = 10.0
secondary_entropy_coef = 0.01
secondary_start_yaw_within_deg = 180.0
start_stage_behaviours = ["spread", "squeeze"]
start_stage_initial = 0.0
start_stage_step = 0.1
start_stage_success_rate = 0.5
start_stage_window = 3
secondary_stop_success_rate = 0.0
secondary_stop_window = 10

[curriculum.secondary_env_steps_by_behaviour]
"#;

/// configs/smoke.toml as loaded.
const SMOKE: &str = r#"[run]
scene_kind = "straight"
steps_per_iteration = 1000
num_envs = 50
total_env_steps = 40000
max_episode_steps = 50
invalid_reward = -0.1
checkpoint_interval = 5
threads = 2
backend = "flex"
start_yaw_within_deg = 180.0
start_stage = 1.0
start_stage_step = 0.1
start_stage_success_rate = 0.5
start_stage_window = 3
failure_resample_probability = 0.0
failure_memory_per_env = 8
composed_share = 0.0
exit_share = 0.0
exit_behaviour = "squeeze"
composed_from_env_steps = 0
stop_success_rate = 0.0
stop_window = 10
robot = ""

[ppo]
learning_rate = 0.0025
anneal_start_env_steps = 0
adam_epsilon = 0.00001
gamma = 0.95
gae_lambda = 0.9
clip_epsilon = 0.2
policy_coef = 1.0
value_coef = 0.5
entropy_coef = 0.0
epochs = 10
minibatch_size = 250
max_grad_norm = 0.5
normalize_advantages = true
target_kl = 0.05
conv_kernel = "native"

[network]
conv_channels = [16, 32, 32]
hidden = [128]

[curriculum]
behaviours = ["straight", "around", "lift", "spread", "squeeze"]
secondary_steps_per_iteration = 3000
secondary_env_steps = 300000
keep_trajectories = 1000
randomizations = 1000
replay_steps_per_iteration = 2000
replay_imitation_coef = 0.0
replay_balance = "trajectory"
label_steps_per_iteration = 2000
label_imitation_coef = 0.5
primary_init = "scratch"
secondary_init_temperature = 1.0
secondary_entropy_coef = 0.003
secondary_start_yaw_within_deg = 180.0
start_stage_behaviours = []
start_stage_initial = 0.0
start_stage_step = 0.1
start_stage_success_rate = 0.5
start_stage_window = 3
secondary_stop_success_rate = 0.0
secondary_stop_window = 10

[curriculum.secondary_env_steps_by_behaviour]
"#;

/// The shipped recipe with `changes` made, each `(key = old, key = new)`; every old line must
/// be in it once.
fn shipped_with(changes: &[(&str, &str)]) -> String {
    let mut text = SHIPPED.to_string();
    for (old, new) in changes {
        assert_eq!(
            text.matches(old).count(),
            1,
            "`{old}` in the shipped recipe"
        );
        text = text.replace(old, new);
    }
    text
}

/// configs/shipped-exit.toml: the primary continued past 30 M with squeeze exit scenes, its
/// rate falling from 0.0005 at 29 M to 0 at 33 M (the shipped file's run stops at 31 M).
fn shipped_exit() -> String {
    shipped_with(&[
        ("total_env_steps = 30000000", "total_env_steps = 33000000"),
        ("exit_share = 0.0", "exit_share = 0.15"),
        ("learning_rate = 0.001", "learning_rate = 0.0005"),
        (
            "anneal_start_env_steps = 26000000",
            "anneal_start_env_steps = 29000000",
        ),
    ])
}

/// configs/dagger.toml: one round from a checkpoint on the exit stage's scenes (composed ones
/// from its first step, since the round counts its own env steps from 0), 1 M env steps at a
/// rate of 0.0002 annealed to 0 over the round.
fn dagger() -> String {
    shipped_with(&[
        ("total_env_steps = 30000000", "total_env_steps = 1000000"),
        (
            "composed_from_env_steps = 10000000",
            "composed_from_env_steps = 0",
        ),
        ("exit_share = 0.0", "exit_share = 0.15"),
        ("learning_rate = 0.001", "learning_rate = 0.0002"),
        (
            "anneal_start_env_steps = 26000000",
            "anneal_start_env_steps = 0",
        ),
    ])
}

/// Each recipe with the config it must resolve to.
fn recipes() -> [(&'static str, String); 5] {
    [
        ("shipped.toml", SHIPPED.to_string()),
        ("shipped-exit.toml", shipped_exit()),
        ("baseline.toml", BASELINE.to_string()),
        ("dagger.toml", dagger()),
        ("smoke.toml", SMOKE.to_string()),
    ]
}

fn recipe(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../configs")
        .join(name)
}

#[test]
fn each_recipe_resolves_to_its_recorded_config() {
    for (name, expected) in recipes() {
        let loaded = TrainConfig::load(&recipe(name)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            loaded.to_toml(),
            expected,
            "configs/{name} resolves differently"
        );
        let recorded = TrainConfig::from_toml(&expected).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(loaded, recorded, "configs/{name}");
    }
}

#[test]
fn each_recipe_stands_alone() {
    for (name, _) in recipes() {
        let text = std::fs::read_to_string(recipe(name)).unwrap();
        assert!(
            !text.contains("extends"),
            "configs/{name} must not extend another config: write every key out"
        );
    }
}

/// A resolved config without what a stage resumed past `env_steps` cannot tell apart: when
/// composed scenes began (once begun, they stay) and the secondaries' budgets.
fn as_resumed_past(config: &TrainConfig, env_steps: u64) -> String {
    assert!(config.run.composed_from_env_steps <= env_steps);
    let text = config.to_toml();
    let text = text
        .split('\n')
        .filter(|line| !line.starts_with("composed_from_env_steps"))
        .collect::<Vec<_>>()
        .join("\n");
    text.split("[curriculum.secondary_env_steps_by_behaviour]")
        .next()
        .unwrap()
        .to_string()
}

#[test]
fn the_exit_stage_written_out_is_the_stage_that_made_the_shipped_file() {
    let written_out = TrainConfig::load(&recipe("shipped-exit.toml")).unwrap();
    let as_run = TrainConfig::load(&recipe("comparisons/curriculum-bc-exit.toml")).unwrap();
    assert_eq!(
        as_resumed_past(&written_out, 29_000_000),
        as_resumed_past(&as_run, 29_000_000)
    );
}
