//! The host's board: what the control loop ([`wheelleg_control::Control`]) runs on when it runs
//! on the host. Its CAN peripheral is a [`Transport`] (the in-process bus with the simulated
//! axes on it, SocketCAN, or an SLCAN adapter); its period's clock is simulated time on the
//! in-process bus (the axes' physics run between two periods) and the wall clock otherwise.
//! It logs and counts every frame, keeps the ground truth the loop cannot see, and injects the
//! faults a test asks for: axes falling silent or off the bus, a hung transmit path, a lost
//! link, a peripheral that refuses frames.

use super::config::{RigError, TimedFault, TrafficCounts, TrueSample};
use crate::bus::{Faults, InProcessBus, Port, Transport};
use crate::candump::CandumpWriter;
use crate::firmware::Firmware;
use embedded_can::ErrorKind;
use std::io::Write;
use wheelleg_control::Board;
use wheelleg_runtime::base::{MecanumBase, Odometry, WheelSpeeds};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::Robot;

/// The simulated axes (or a remote bus) and the loop's CAN peripheral, one control period per
/// [`Board::tick_done`].
pub struct RigBoard {
    robot: Robot,
    period_us: u64,
    physics_dt_us: u64,
    bus: InProcessBus,
    host: Box<dyn Transport>,
    firmware: Firmware,
    /// The simulated axes' port on the in-process bus; `None` when the motors are elsewhere
    /// (another process on SocketCAN, or real hardware) and time is real.
    firmware_port: Option<Port>,
    /// Wall-clock origin when time is real.
    realtime_origin: Option<std::time::Instant>,
    now_us: u64,
    log: Option<CandumpWriter<Box<dyn Write>>>,
    traffic: TrafficCounts,
    /// Faults still to inject, (time, fault).
    scheduled: Vec<(u64, TimedFault)>,
    /// Pose integrated from the simulated wheels' true speeds (in-process only).
    true_odometry: Odometry,
    /// Ground truth at the end of every control period, while recording.
    truth: Option<Vec<TrueSample>>,
    /// The transmit path hangs: frames the loop sends go nowhere.
    commands_paused: bool,
    /// The link to the bus is lost: nothing crosses it, and [`Board::link_lost`] says so.
    link_lost: bool,
    /// The peripheral refuses every frame.
    refusing: bool,
    /// Every frame the peripheral took, by period, while recording.
    sent: Option<Vec<Vec<CanFrame>>>,
    /// The first transport or log error since the rig last looked.
    error: Option<RigError>,
}

impl RigBoard {
    /// The robot's 16 simulated axes on an in-process bus with `faults`, legs at `start`,
    /// wheels at rest, all idle; their watchdog idles an armed axis that hears no setpoint for
    /// `watchdog_timeout_us` (0: off). Time is simulated: `period_us` per control period in
    /// physics steps of `physics_dt_us`.
    pub fn in_process(
        robot: &Robot,
        start: LegConfig,
        faults: Faults,
        watchdog_timeout_us: u64,
        period_us: u64,
        physics_dt_us: u64,
    ) -> Result<RigBoard, RigError> {
        let bus = InProcessBus::new(faults);
        let host = bus.port();
        let firmware_port = bus.port();
        let mut firmware = Firmware::for_robot(&robot.geometry, &robot.can, start)?;
        firmware.set_watchdog_timeout_us(watchdog_timeout_us);
        Ok(RigBoard::new(
            robot,
            period_us,
            physics_dt_us.max(1),
            bus,
            Box::new(host),
            firmware,
            Some(firmware_port),
            None,
        ))
    }

    /// A board whose motors are on `host`'s bus elsewhere: no local simulation, control periods
    /// paced by the wall clock.
    pub fn remote(robot: &Robot, host: Box<dyn Transport>, period_us: u64) -> RigBoard {
        RigBoard::new(
            robot,
            period_us,
            period_us.max(1),
            InProcessBus::new(Faults::NONE),
            host,
            Firmware::new(Vec::new(), robot.can),
            None,
            Some(std::time::Instant::now()),
        )
    }

    #[allow(clippy::too_many_arguments)]
    fn new(
        robot: &Robot,
        period_us: u64,
        physics_dt_us: u64,
        bus: InProcessBus,
        host: Box<dyn Transport>,
        firmware: Firmware,
        firmware_port: Option<Port>,
        realtime_origin: Option<std::time::Instant>,
    ) -> RigBoard {
        RigBoard {
            robot: *robot,
            period_us,
            physics_dt_us,
            bus,
            host,
            firmware,
            firmware_port,
            realtime_origin,
            now_us: 0,
            log: None,
            traffic: TrafficCounts::default(),
            scheduled: Vec::new(),
            true_odometry: Odometry::default(),
            truth: None,
            commands_paused: false,
            link_lost: false,
            refusing: false,
            sent: None,
            error: None,
        }
    }

    /// Simulated (or, for a remote bus, wall-clock) time since the board was made.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// The simulated axes (none for a remote bus).
    pub fn firmware(&self) -> &Firmware {
        &self.firmware
    }

    /// The simulated axes, for fault injection.
    pub fn firmware_mut(&mut self) -> &mut Firmware {
        &mut self.firmware
    }

    /// The in-process bus (fault counters, changing faults).
    pub fn bus(&self) -> &InProcessBus {
        &self.bus
    }

    /// Everything on the bus so far.
    pub fn traffic(&self) -> TrafficCounts {
        self.traffic
    }

    /// Logs every frame the loop sends or receives, in `candump -L` format.
    pub fn log_to(&mut self, writer: CandumpWriter<Box<dyn Write>>) {
        self.log = Some(writer);
    }

    /// Stops logging and returns the writer (flushed).
    pub fn take_log(&mut self) -> Result<Option<Box<dyn Write>>, RigError> {
        match self.log.take() {
            Some(w) => Ok(Some(w.finish()?)),
            None => Ok(None),
        }
    }

    /// The first transport or log error since the last call: the loop only sees that the
    /// peripheral failed, the rig reports why.
    pub fn take_error(&mut self) -> Option<RigError> {
        self.error.take()
    }

    /// Injects `fault` at the first physics step at or after `at_us` (in-process bus only).
    pub fn schedule(&mut self, at_us: u64, fault: TimedFault) {
        self.scheduled.push((at_us, fault));
    }

    /// Simulates a loop whose transmit path hangs: it keeps listening but nothing it sends
    /// reaches the bus.
    pub fn pause_commands(&mut self, paused: bool) {
        self.commands_paused = paused;
    }

    /// Loses (or restores) the link to the bus: [`Board::link_lost`] says so, and nothing
    /// crosses it either way.
    pub fn set_link_lost(&mut self, lost: bool) {
        self.link_lost = lost;
    }

    /// Makes the peripheral refuse (or take again) every frame.
    pub fn set_refusing(&mut self, refusing: bool) {
        self.refusing = refusing;
    }

    /// Starts recording every frame the peripheral takes, by period.
    pub fn record_sent(&mut self) {
        self.sent.get_or_insert_with(Vec::new);
    }

    /// The frames the peripheral took, by period, since [`Self::record_sent`].
    pub fn sent(&self) -> &[Vec<CanFrame>] {
        self.sent.as_deref().unwrap_or(&[])
    }

    /// Where the robot really is relative to where it started: odometry of the simulated
    /// wheels' true speeds at every physics step, with the true leg track. Identity for a
    /// remote bus.
    pub fn true_pose(&self) -> nalgebra::Isometry2<f32> {
        self.true_odometry.pose
    }

    /// The legs as the simulated joints really are (forward kinematics of their true
    /// positions, averaged over the four legs); `None` for a remote bus.
    pub fn true_legs(&self) -> Option<LegConfig> {
        self.firmware
            .true_legs(&self.robot.can, &self.robot.geometry)
    }

    fn true_wheel_speeds(&self) -> Option<WheelSpeeds> {
        self.firmware.true_wheel_speeds(&self.robot.can)
    }

    /// Starts (or stops) recording the ground truth at the end of every control period.
    pub fn record_truth(&mut self, on: bool) {
        match (on, &self.truth) {
            (true, None) => self.truth = Some(Vec::new()),
            (false, Some(_)) => self.truth = None,
            _ => {}
        }
    }

    /// The ground truth recorded since the last call (empty when not recording).
    pub fn take_truth(&mut self) -> Vec<TrueSample> {
        self.truth.as_mut().map(std::mem::take).unwrap_or_default()
    }

    fn fail(&mut self, error: RigError) {
        self.error.get_or_insert(error);
    }

    /// Lets the motors run until the next period: simulated physics on the in-process bus,
    /// the wall clock otherwise.
    fn advance(&mut self) -> Result<(), RigError> {
        let end_us = self.now_us + self.period_us;
        match (self.firmware_port.is_some(), self.realtime_origin) {
            (true, _) => {
                let dt_s = self.physics_dt_us as f32 * 1e-6;
                while self.now_us < end_us {
                    self.now_us += self.physics_dt_us;
                    if let Some(port) = &mut self.firmware_port {
                        self.firmware.run(port, self.now_us, dt_s)?;
                    }
                    if let (Some(legs), Some(wheels)) = (self.true_legs(), self.true_wheel_speeds())
                    {
                        let base = MecanumBase::at(&self.robot.geometry, legs)?;
                        self.true_odometry.integrate_wheels(&base, wheels, dt_s)?;
                    }
                    if !self.scheduled.is_empty() {
                        self.inject_due_faults();
                    }
                }
                if self.truth.is_some() {
                    if let Some(legs) = self.true_legs() {
                        let sample = TrueSample {
                            at_us: self.now_us,
                            pose: self.true_odometry.pose,
                            legs,
                        };
                        self.truth.get_or_insert_with(Vec::new).push(sample);
                    }
                }
            }
            (false, Some(origin)) => {
                let deadline = origin + std::time::Duration::from_micros(end_us);
                if let Some(wait) = deadline.checked_duration_since(std::time::Instant::now()) {
                    std::thread::sleep(wait);
                }
                self.now_us = end_us.max(origin.elapsed().as_micros() as u64);
            }
            (false, None) => self.now_us = end_us,
        }
        Ok(())
    }

    /// Applies the scheduled faults that are due now.
    fn inject_due_faults(&mut self) {
        let now_us = self.now_us;
        let (due, later): (Vec<_>, Vec<_>) = self
            .scheduled
            .drain(..)
            .partition(|(at_us, _)| *at_us <= now_us);
        self.scheduled = later;
        for (_, fault) in due {
            match fault {
                TimedFault::Silence(axis) => {
                    if let Some(motor) = self.firmware.axis_mut(axis) {
                        motor.set_silent(true);
                    }
                }
                TimedFault::Disconnect(axis) => {
                    if let Some(motor) = self.firmware.axis_mut(axis) {
                        motor.set_silent(true);
                        motor.set_deaf(true);
                    }
                }
                TimedFault::HangCommands => self.commands_paused = true,
            }
        }
    }
}

impl embedded_can::nb::Can for RigBoard {
    type Frame = CanFrame;
    type Error = ErrorKind;

    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, ErrorKind> {
        if self.refusing {
            return Err(nb::Error::Other(ErrorKind::Other));
        }
        if let Some(period) = self.sent.as_mut().and_then(|sent| sent.last_mut()) {
            period.push(*frame);
        }
        // A hung transmit path and a lost link both take the frame and lose it.
        if self.commands_paused || self.link_lost {
            return Ok(None);
        }
        if let Some(log) = &mut self.log {
            if let Err(error) = log.log(self.now_us, frame) {
                self.fail(error.into());
            }
        }
        self.traffic.count(frame);
        match self.host.send(frame, self.now_us) {
            Ok(()) => Ok(None),
            Err(error) => {
                self.fail(error.into());
                Err(nb::Error::Other(ErrorKind::Other))
            }
        }
    }

    fn receive(&mut self) -> nb::Result<CanFrame, ErrorKind> {
        loop {
            match self.host.recv(self.now_us) {
                // What the axes send while the link is lost never arrives.
                Ok(Some(_)) if self.link_lost => continue,
                Ok(Some(frame)) => {
                    if let Some(log) = &mut self.log {
                        if let Err(error) = log.log(self.now_us, &frame) {
                            self.fail(error.into());
                        }
                    }
                    self.traffic.count(&frame);
                    return Ok(frame);
                }
                Ok(None) => return Err(nb::Error::WouldBlock),
                Err(error) => {
                    self.fail(error.into());
                    return Err(nb::Error::Other(ErrorKind::Other));
                }
            }
        }
    }
}

impl Board for RigBoard {
    type Frame = CanFrame;
    type Can = RigBoard;

    fn can(&mut self) -> &mut RigBoard {
        self
    }

    /// A period begins where the last one's motors stopped: nothing to wait for.
    fn wait_for_tick(&mut self) {
        if let Some(sent) = &mut self.sent {
            sent.push(Vec::new());
        }
    }

    fn link_lost(&self) -> bool {
        self.link_lost
    }

    /// The period's frames are out: the motors run until the next period.
    fn tick_done(&mut self) {
        if let Err(error) = self.advance() {
            self.fail(error);
        }
    }
}
