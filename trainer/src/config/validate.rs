//! The ranges every key must lie in, each error naming its key.

use super::*;

impl TrainConfig {
    /// Checks ranges, naming the offending key.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let r = &self.run;
        let p = &self.ppo;
        let check = |ok: bool, what: &str| {
            if ok {
                Ok(())
            } else {
                Err(ConfigError::Invalid(what.to_string()))
            }
        };
        check(
            wheelleg_sim::generate::SceneKind::from_name(&r.scene_kind).is_some(),
            "run.scene_kind must be one of straight, around, lift, spread, squeeze, complex, composed",
        )?;
        check(
            (0.0..=1.0).contains(&r.composed_share),
            "run.composed_share must be between 0 and 1",
        )?;
        check(
            (0.0..=1.0).contains(&r.exit_share) && r.composed_share + r.exit_share <= 1.0,
            "run.exit_share must be between 0 and 1, and with run.composed_share at most 1",
        )?;
        check(
            wheelleg_sim::generate::Behaviour::from_name(&r.exit_behaviour)
                .is_some_and(|b| b.has_fence()),
            "run.exit_behaviour must be one of lift, spread, squeeze",
        )?;
        check(r.num_envs >= 1, "run.num_envs must be at least 1")?;
        check(
            r.steps_per_iteration >= r.num_envs,
            "run.steps_per_iteration must be at least run.num_envs",
        )?;
        check(
            r.max_episode_steps >= 1,
            "run.max_episode_steps must be at least 1",
        )?;
        check(
            r.invalid_reward.is_finite() && r.invalid_reward <= 0.0,
            "run.invalid_reward must be a number <= 0 (the paper: -0.1)",
        )?;
        check(
            r.checkpoint_interval >= 1,
            "run.checkpoint_interval must be at least 1",
        )?;
        check(r.threads >= 1, "run.threads must be at least 1")?;
        check(
            r.start_yaw_within_deg.is_finite() && r.start_yaw_within_deg >= 0.0,
            "run.start_yaw_within_deg must be a non-negative number of degrees",
        )?;
        check(
            r.start_stage.is_finite() && (0.0..=1.0).contains(&r.start_stage),
            "run.start_stage must be in [0, 1] (1: off)",
        )?;
        check(
            r.start_stage_step.is_finite() && r.start_stage_step > 0.0,
            "run.start_stage_step must be a positive number",
        )?;
        check(
            (0.0..=1.0).contains(&r.start_stage_success_rate),
            "run.start_stage_success_rate must be in [0, 1]",
        )?;
        check(
            r.start_stage_window >= 1,
            "run.start_stage_window must be at least 1",
        )?;
        check(
            (0.0..=1.0).contains(&r.stop_success_rate),
            "run.stop_success_rate must be in [0, 1] (0: off)",
        )?;
        check(r.stop_window >= 1, "run.stop_window must be at least 1")?;
        check(
            (0.0..=1.0).contains(&r.failure_resample_probability),
            "run.failure_resample_probability must be in [0, 1] (0: off)",
        )?;
        crate::network::BackendKind::from_name(&r.backend)
            .map_err(|e| ConfigError::Invalid(e.to_string()))?;
        crate::conv_kernel::ConvKernel::from_name(&p.conv_kernel)
            .map_err(|e| ConfigError::Invalid(e.to_string()))?;
        check(p.learning_rate > 0.0, "ppo.learning_rate must be positive")?;
        check(
            p.learning_rate_final.is_none_or(|lr| lr >= 0.0),
            "ppo.learning_rate_final must be >= 0",
        )?;
        check(
            p.learning_rate_final.is_none() || p.anneal_start_env_steps < r.total_env_steps,
            "ppo.anneal_start_env_steps must be below run.total_env_steps",
        )?;
        check(
            (0.0..=1.0).contains(&p.gamma),
            "ppo.gamma must be in [0, 1]",
        )?;
        check(
            (0.0..=1.0).contains(&p.gae_lambda),
            "ppo.gae_lambda must be in [0, 1]",
        )?;
        check(p.clip_epsilon > 0.0, "ppo.clip_epsilon must be positive")?;
        check(p.epochs >= 1, "ppo.epochs must be at least 1")?;
        check(
            p.minibatch_size >= 2,
            "ppo.minibatch_size must be at least 2",
        )?;
        check(p.max_grad_norm >= 0.0, "ppo.max_grad_norm must be >= 0")?;
        check(p.target_kl >= 0.0, "ppo.target_kl must be >= 0")?;
        check(
            !self.network.conv_channels.is_empty()
                && self.network.conv_channels.iter().all(|&c| c > 0),
            "network.conv_channels must be non-empty positive widths",
        )?;
        check(
            self.network.hidden.iter().all(|&h| h > 0),
            "network.hidden widths must be positive",
        )?;
        let c = &self.curriculum;
        check(
            c.behaviours.first().map(String::as_str) == Some("straight")
                && c.behaviours.iter().all(|b| {
                    wheelleg_sim::generate::SceneKind::from_name(b)
                        .is_some_and(|k| k != wheelleg_sim::generate::SceneKind::Complex)
                }),
            "curriculum.behaviours must start with straight and name behaviours (straight, \
             around, lift, spread, squeeze)",
        )?;
        check(
            c.secondary_steps_per_iteration >= r.num_envs,
            "curriculum.secondary_steps_per_iteration must be at least run.num_envs",
        )?;
        check(
            c.primary_init == "scratch" || c.behaviours.contains(&c.primary_init),
            "curriculum.primary_init must be scratch or one of curriculum.behaviours",
        )?;
        check(
            c.secondary_init_temperature.is_finite() && c.secondary_init_temperature > 0.0,
            "curriculum.secondary_init_temperature must be a positive number",
        )?;
        check(
            c.replay_imitation_coef.is_finite() && c.replay_imitation_coef >= 0.0,
            "curriculum.replay_imitation_coef must be a non-negative number",
        )?;
        check(
            c.label_imitation_coef.is_finite() && c.label_imitation_coef >= 0.0,
            "curriculum.label_imitation_coef must be a non-negative number",
        )?;
        check(
            c.secondary_entropy_coef.is_finite() && c.secondary_entropy_coef >= 0.0,
            "curriculum.secondary_entropy_coef must be a non-negative number",
        )?;
        check(
            c.secondary_start_yaw_within_deg.is_finite() && c.secondary_start_yaw_within_deg >= 0.0,
            "curriculum.secondary_start_yaw_within_deg must be a non-negative number of degrees",
        )?;
        check(
            c.secondary_env_steps_by_behaviour
                .keys()
                .all(|b| c.behaviours.contains(b)),
            "curriculum.secondary_env_steps_by_behaviour must name behaviours of \
             curriculum.behaviours",
        )?;
        check(
            c.start_stage_behaviours
                .iter()
                .all(|b| b != "straight" && c.behaviours.contains(b)),
            "curriculum.start_stage_behaviours must name behaviours of curriculum.behaviours \
             other than straight",
        )?;
        check(
            c.start_stage_initial.is_finite() && (0.0..=1.0).contains(&c.start_stage_initial),
            "curriculum.start_stage_initial must be in [0, 1]",
        )?;
        check(
            c.start_stage_step.is_finite() && c.start_stage_step > 0.0,
            "curriculum.start_stage_step must be a positive number",
        )?;
        check(
            (0.0..=1.0).contains(&c.start_stage_success_rate),
            "curriculum.start_stage_success_rate must be in [0, 1]",
        )?;
        check(
            c.start_stage_window >= 1,
            "curriculum.start_stage_window must be at least 1",
        )?;
        check(
            (0.0..=1.0).contains(&c.secondary_stop_success_rate),
            "curriculum.secondary_stop_success_rate must be in [0, 1] (0: off)",
        )?;
        check(
            c.secondary_epochs.is_none_or(|e| e >= 1),
            "curriculum.secondary_epochs must be at least 1",
        )?;
        check(
            c.secondary_stop_window >= 1,
            "curriculum.secondary_stop_window must be at least 1",
        )?;
        Ok(())
    }
}
