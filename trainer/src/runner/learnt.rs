//! When a run has learnt its scenes (`run.stop_success_rate`): a secondary policy's success
//! plateaus long before any fixed budget that covers its slowest seed, and every iteration past
//! the plateau is time the recipe spends for nothing.

use super::IterationMetrics;

/// The rule that ends a run before its budget: the training success rate reached
/// `run.stop_success_rate` in each of the last `run.stop_window` iterations, every one of them
/// on the task as specified (start stage 1).
#[derive(Clone, Debug, PartialEq)]
pub struct LearntRule {
    success_rate: f32,
    window: usize,
    /// Iterations in a row, up to the latest, that passed.
    passed_in_a_row: usize,
}

impl LearntRule {
    /// The rule of a run, `None` when it runs to its budget (`run.stop_success_rate` 0).
    pub fn of_run(run: &crate::config::RunConfig) -> Option<LearntRule> {
        (run.stop_success_rate > 0.0).then(|| LearntRule {
            success_rate: run.stop_success_rate,
            window: run.stop_window.max(1),
            passed_in_a_row: 0,
        })
    }

    /// Records one iteration's training success rate and the start stage its episodes were
    /// drawn at (`None`: no start-stage curriculum, the task as specified).
    pub fn record(&mut self, success_rate: f32, start_stage: Option<f32>) {
        let full_task = start_stage.is_none_or(|stage| stage >= 1.0);
        self.passed_in_a_row = if full_task && success_rate >= self.success_rate {
            self.passed_in_a_row + 1
        } else {
            0
        };
    }

    /// Continues from a run's logged iterations (a resumed run decides as the uninterrupted
    /// one would have).
    pub fn restore(&mut self, logged: &[IterationMetrics]) {
        self.passed_in_a_row = 0;
        for m in logged {
            self.record(m.success_rate, m.start_stage);
        }
    }

    /// Whether the run has learnt its scenes.
    pub fn reached(&self) -> bool {
        self.passed_in_a_row >= self.window
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_has_learnt_after_a_full_window_of_passing_iterations_at_the_full_task() {
        let run = crate::config::RunConfig {
            stop_success_rate: 0.9,
            stop_window: 3,
            ..Default::default()
        };
        assert!(LearntRule::of_run(&crate::config::RunConfig::default()).is_none());
        let mut rule = LearntRule::of_run(&run).unwrap();
        rule.record(0.95, None);
        rule.record(0.95, None);
        assert!(!rule.reached(), "two iterations are not a full window");
        rule.record(0.89, None);
        assert!(!rule.reached(), "one under the rate");
        for _ in 0..2 {
            rule.record(1.0, Some(1.0));
            assert!(
                !rule.reached(),
                "the failing iteration is still in the window"
            );
        }
        rule.record(0.9, None);
        assert!(rule.reached());
        rule.record(1.0, Some(0.9));
        assert!(
            !rule.reached(),
            "an early start stage is not the task as specified"
        );
    }
}
