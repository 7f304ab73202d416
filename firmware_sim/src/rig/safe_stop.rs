//! Safe stop: decelerate along the step's own path, then rest; the emergency stop and recovery.

use super::{Rig, RigError, StopReason};
use wheelleg_runtime::base::WheelSpeeds;
use wheelleg_runtime::motion::Setpoint;

impl Rig {
    /// Plans the safe stop the moment it is decided, before this tick's setpoint (tick
    /// `tick_in_step` of the active step) goes out: inside a step, decelerate along the step's
    /// path ([`StepMotion::stop_after`]) for every axis, the silent one included (if it still
    /// hears, it follows; if not, its own watchdog idles it); outside a step, rest where the
    /// last setpoint sent put the robot.
    pub(super) fn begin_stop(&mut self, tick_in_step: u32) {
        self.stopping = self
            .active
            .as_ref()
            .and_then(|motion| motion.stop_after(tick_in_step).ok());
        self.rest = match &self.stopping {
            Some(stop) => Some(stop.rest()),
            None => self.last_sent.map(|sent| Setpoint {
                joint_rates: Default::default(),
                base: wheelleg_runtime::base::BaseVelocity::ZERO,
                wheels: WheelSpeeds::ZERO,
                ..sent
            }),
        };
    }

    /// The safe stop's command for this tick: the next setpoint of the controlled stop, then
    /// its rest pose; `None` when no plan is known (the commander then holds the measured
    /// joints).
    pub(super) fn next_stop_setpoint(&mut self) -> Option<Setpoint> {
        if let Some(stop) = &mut self.stopping {
            match stop.next() {
                Some(setpoint) => return Some(setpoint),
                None => {
                    self.rest = Some(stop.rest());
                    self.stopping = None;
                }
            }
        }
        self.rest
    }

    /// Where the safe stop holds the legs, once it has been decided.
    pub fn stop_rest(&self) -> Option<Setpoint> {
        self.rest
    }

    /// Sends Estop to every axis (they disarm and latch `ESTOP_REQUESTED`) and keeps the rig in
    /// safe stop; then runs one control period so the motors see it.
    pub fn estop(&mut self) -> Result<(), RigError> {
        self.commander.queue_estop(&mut self.tx)?;
        let health = self
            .tracker
            .health(self.now_us, self.config.health_timeout_us);
        if self.stopped.is_none() {
            self.stopped = Some(StopReason::AxisError(health.errored));
            self.stopped_at_us = Some(self.now_us);
            self.begin_stop(0);
        }
        let hold = Setpoint::hold(&self.robot.geometry, self.legs)?;
        self.control_tick(&hold, false)
    }

    /// Recovers from a stop: the start-up sequence again ([`Rig::start_up`]: roll call,
    /// Clear_Errors to every axis, arming). Axes still armed get no setpoint during the roll
    /// call, so their watchdog may idle them first (the robot is at rest); all re-arm where they
    /// are, then move (within their speed limits) to the commanded legs; the odometry pose is
    /// kept.
    pub fn recover(&mut self) -> Result<(), RigError> {
        self.stopped = None;
        self.stopped_at_us = None;
        self.stopping = None;
        self.rest = None;
        self.commands_paused = false;
        self.start_up()
    }
}
