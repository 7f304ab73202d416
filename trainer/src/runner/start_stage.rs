//! The start-stage curriculum's schedule (`run.start_stage`): which stage of the scenes a run
//! draws next, advanced on the success of the episodes started at the current stage.

use crate::error::TrainError;

/// The start-stage curriculum's schedule (`run.start_stage`): the stage of the scenes drawn
/// next, advanced by `run.start_stage_step` (up to 1, the task as specified) each time the
/// success rate of the episodes started at the current stage, over the last
/// `run.start_stage_window` iterations at that stage, reaches `run.start_stage_success_rate`.
#[derive(Clone, Debug, PartialEq)]
pub struct StartStageSchedule {
    stage: f32,
    step: f32,
    success_rate: f32,
    window_len: usize,
    window: std::collections::VecDeque<(u32, u32)>,
}

impl StartStageSchedule {
    /// The schedule of a run, `None` when its curriculum is off (`run.start_stage` 1).
    pub fn of_run(run: &crate::config::RunConfig) -> Option<StartStageSchedule> {
        (run.start_stage < 1.0).then(|| StartStageSchedule {
            stage: run.start_stage.max(0.0),
            step: run.start_stage_step,
            success_rate: run.start_stage_success_rate,
            window_len: run.start_stage_window.max(1),
            window: Default::default(),
        })
    }

    /// Stage of the scenes drawn next.
    pub fn stage(&self) -> f32 {
        self.stage
    }

    /// The window's (successes, episodes) per iteration, oldest first.
    pub fn window(&self) -> Vec<(u32, u32)> {
        self.window.iter().copied().collect()
    }

    /// Continues from a checkpoint's stage and window.
    pub fn restore(&mut self, stage: f32, window: &[(u32, u32)]) -> Result<(), TrainError> {
        if !(stage.is_finite() && (0.0..=1.0).contains(&stage)) || window.len() > self.window_len {
            return Err(TrainError::StartStageMismatch {
                stage,
                entries: window.len(),
            });
        }
        self.stage = stage;
        self.window = window.iter().copied().collect();
        Ok(())
    }

    /// Records one iteration's episodes that started at the current stage; returns whether the
    /// stage advanced (the window then starts again).
    pub fn record(&mut self, successes: u32, episodes: u32) -> bool {
        self.window.push_back((successes, episodes));
        while self.window.len() > self.window_len {
            self.window.pop_front();
        }
        let (s, e) = self
            .window
            .iter()
            .fold((0u64, 0u64), |(s, e), &(a, b)| (s + a as u64, e + b as u64));
        let passed = self.window.len() == self.window_len
            && e > 0
            && s as f64 >= self.success_rate as f64 * e as f64;
        if passed && self.stage < 1.0 {
            // Rounded to 1e-4 so that ten steps of 0.1 land on 1 exactly, not 0.99999994.
            self.stage = (((self.stage + self.step) * 1.0e4).round() / 1.0e4).min(1.0);
            self.window.clear();
            return true;
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_start_stage_advances_on_a_full_window_of_successes_and_stops_at_one() {
        let run = crate::config::RunConfig {
            start_stage: 0.0,
            start_stage_step: 0.25,
            start_stage_success_rate: 0.5,
            start_stage_window: 2,
            ..Default::default()
        };
        assert!(StartStageSchedule::of_run(&crate::config::RunConfig::default()).is_none());
        let mut s = StartStageSchedule::of_run(&run).unwrap();
        assert!(!s.record(10, 10), "one iteration is not a full window");
        assert!(s.record(0, 10), "10 of 20");
        assert_eq!(s.stage(), 0.25);
        assert!(s.window().is_empty());
        assert!(!s.record(4, 10));
        assert!(!s.record(5, 10), "9 of 20");
        assert!(s.record(6, 10), "the window slides: 11 of the last 20");
        assert_eq!(s.stage(), 0.5);
        for expected in [0.75, 1.0] {
            assert!(!s.record(9, 10) && s.record(9, 10));
            assert_eq!(s.stage(), expected);
        }
        assert!(!s.record(9, 10) && !s.record(9, 10) && s.stage() == 1.0);
        let mut r = StartStageSchedule::of_run(&run).unwrap();
        r.restore(0.5, &[(3, 4)]).unwrap();
        assert!(r.restore(0.5, &[(1, 1), (1, 1), (1, 1)]).is_err());
        assert!(r.restore(1.5, &[]).is_err());
    }
}
