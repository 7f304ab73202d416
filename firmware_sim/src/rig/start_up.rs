//! Start-up: the roll call (who is on each node, and on what firmware), Clear_Errors, arming.

use super::{Rig, RigError};
use wheelleg_runtime::can::host::{RollCall, ROLL_CALL_ROUNDS, ROLL_CALL_ROUND_US};
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::can::protocol::AxisState;
use wheelleg_runtime::motion::Setpoint;

/// Control ticks the start pose is held after arming: a few heartbeat periods, enough for
/// every axis to report its new state.
pub const STARTUP_TICKS: u32 = 30;

impl Rig {
    /// Starts the robot: asks every node of the map for its version and refuses to go on if a
    /// node is missing, two devices share a node id, or a node runs firmware the codec does not
    /// speak ([`RigError::StartupRefused`], naming the node); then clears every axis's latched
    /// errors, arms every axis and holds the start pose until all report closed loop.
    ///
    /// A bus on which nothing at all is heard is [`RigError::StartupFailed`] (every node
    /// silent): no motor controller is there to refuse.
    pub fn start_up(&mut self) -> Result<(), RigError> {
        self.roll_call()?;
        self.commander.queue_clear_errors(&mut self.tx)?;
        self.commander.queue_startup(&mut self.tx)?;
        let hold = Setpoint::hold(&self.robot.geometry, self.legs)?;
        for _ in 0..STARTUP_TICKS {
            self.control_tick(&hold, false)?;
        }
        let health = self
            .tracker
            .health(self.now_us, self.config.health_timeout_us);
        let all_armed = Axis::ALL.into_iter().all(|a| {
            self.tracker
                .axis(a)
                .is_some_and(|f| f.axis_state == Some(AxisState::ClosedLoopControl))
        });
        if !health.is_ok() || !all_armed {
            return Err(RigError::StartupFailed(health));
        }
        Ok(())
    }

    /// [`ROLL_CALL_ROUNDS`] rounds of Get_Version requests to every node, each round
    /// [`ROLL_CALL_ROUND_US`] long; nothing but the requests is sent, so nothing moves.
    fn roll_call(&mut self) -> Result<(), RigError> {
        let tick_us = ((1e6 * self.tick_s()) as u64).max(1);
        let ticks_per_round = ROLL_CALL_ROUND_US.div_ceil(tick_us).max(1);
        let mut roll_call = RollCall::new(self.robot.can);
        for _ in 0..ROLL_CALL_ROUNDS {
            for tick in 0..ticks_per_round {
                // What arrived during the previous tick belongs to the previous round.
                self.read_feedback(Some(&mut roll_call))?;
                if tick == 0 {
                    roll_call.begin_round();
                    self.commander.queue_version_requests(&mut self.tx)?;
                }
                self.flush_tx()?;
                self.advance_tick()?;
            }
        }
        // The verdict stands on what the periods' reads brought, as on the controller
        // (`control/src/lib.rs`), whose reads come only at a period's start: frames of
        // the last period reach the tracker at the next one.
        match roll_call.verdict() {
            Ok(()) => Ok(()),
            Err(_) if roll_call.heard().is_empty() => Err(RigError::StartupFailed(
                self.tracker
                    .health(self.now_us, self.config.health_timeout_us),
            )),
            Err(refusal) => Err(RigError::StartupRefused(refusal)),
        }
    }
}
