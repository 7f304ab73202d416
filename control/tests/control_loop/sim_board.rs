//! A test board: the 16 simulated ODrive axes on an in-process bus, advanced one control period
//! (ten 1 ms physics steps, as the host's rig and the firmware-in-the-loop plant run them) at
//! each period's start, behind an `embedded_can::nb::Can` that records every frame the loop
//! sends, with switches for the faults the loop must survive.

use embedded_can::ErrorKind;
use wheelleg_control::{Board, Control, ControlError, Finished, SETTLE_S, TX_FRAMES};
use wheelleg_firmware_sim::bus::{InProcessBus, Port, Transport};
use wheelleg_firmware_sim::firmware::Firmware;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::can::host::{Commander, TxQueue};
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::can::protocol::{decode, Message};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::{MotionConfig, Setpoint, StepMotion};
use wheelleg_runtime::robot::Robot;

/// The control period, as the loop's default motion settings run it.
pub const PERIOD_US: u64 = 10_000;
/// The motors' physics step (the rig's).
pub const PHYSICS_US: u64 = 1_000;
/// The axes' watchdog, as the rig and the firmware-in-the-loop plant configure it.
pub const WATCHDOG_TIMEOUT_US: u64 = 100_000;
/// Measured legs against the target after a step and its settling: the closed loop's
/// tolerance (docs/can-protocol.md, "Tolerances of the closed loop").
pub const LEG_TOLERANCE_M: f32 = 0.0005;
/// Achieved base motion against the ideal one, the same tolerance.
pub const POSITION_TOLERANCE_M: f32 = 0.002;
/// Achieved heading against the ideal one, the same tolerance: 0.2°.
pub const YAW_TOLERANCE_RAD: f32 = 0.2 * std::f32::consts::PI / 180.0;

/// The shipped robot.
pub fn robot() -> Robot {
    Robot::WHEELLEG
}

/// The shipped robot's default legs: a start pose the simulated axes take (their motor
/// positions come from its leg IK).
pub fn start_legs() -> LegConfig {
    let geometry = robot().geometry;
    LegConfig {
        clearance_m: geometry.default_clearance_m,
        track_m: geometry.default_track_m,
    }
}

/// The CAN peripheral of [`SimBoard`]: the loop's port on the in-process bus.
pub struct SimCan {
    port: Port,
    now_us: u64,
    link_lost: bool,
    refuse: bool,
    /// Every frame the peripheral took, by period.
    sent: Vec<Vec<CanFrame>>,
}

impl embedded_can::nb::Can for SimCan {
    type Frame = CanFrame;
    type Error = ErrorKind;

    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, ErrorKind> {
        if self.refuse {
            return Err(nb::Error::Other(ErrorKind::Other));
        }
        if let Some(period) = self.sent.last_mut() {
            period.push(*frame);
        }
        // A lost link takes the frame and loses it, as an adapter that stopped answering does.
        if !self.link_lost {
            self.port
                .send(frame, self.now_us)
                .map_err(|_| nb::Error::Other(ErrorKind::Other))?;
        }
        Ok(None)
    }

    fn receive(&mut self) -> nb::Result<CanFrame, ErrorKind> {
        match self.port.recv(self.now_us) {
            // What the axes send while the link is lost never arrives.
            Ok(Some(_)) if self.link_lost => {
                while let Ok(Some(_)) = self.port.recv(self.now_us) {}
                Err(nb::Error::WouldBlock)
            }
            Ok(Some(frame)) => Ok(frame),
            Ok(None) => Err(nb::Error::WouldBlock),
            Err(_) => Err(nb::Error::Other(ErrorKind::Other)),
        }
    }
}

/// The simulated axes and the loop's CAN peripheral, one control period per
/// [`Board::wait_for_tick`].
pub struct SimBoard {
    axes: Firmware,
    axes_port: Port,
    can: SimCan,
    robot: Robot,
    now_us: u64,
    periods: u64,
}

impl SimBoard {
    /// The robot's axes with the legs at `start`, wheels at rest, all idle, watchdog on.
    pub fn new(robot: &Robot, start: LegConfig) -> SimBoard {
        let bus = InProcessBus::default();
        let mut axes = Firmware::for_robot(&robot.geometry, &robot.can, start).unwrap();
        axes.set_watchdog_timeout_us(WATCHDOG_TIMEOUT_US);
        SimBoard {
            axes,
            axes_port: bus.port(),
            can: SimCan {
                port: bus.port(),
                now_us: 0,
                link_lost: false,
                refuse: false,
                sent: Vec::new(),
            },
            robot: *robot,
            now_us: 0,
            periods: 0,
        }
    }

    /// The simulated axes (their true state).
    pub fn axes(&self) -> &Firmware {
        &self.axes
    }

    /// Makes `axis` stop transmitting from the next period on (it still obeys commands).
    pub fn silence(&mut self, axis: Axis) {
        self.axes.axis_mut(axis).unwrap().set_silent(true);
    }

    /// Makes `axis` latch an error (an emergency stop): its heartbeats report it from the next
    /// one on.
    pub fn fault(&mut self, axis: Axis) {
        let now_us = self.now_us;
        self.axes
            .axis_mut(axis)
            .unwrap()
            .handle(&Message::Estop, now_us);
    }

    /// Loses (or restores) the link to the bus: [`Board::link_lost`] says so, and nothing
    /// crosses it either way.
    pub fn set_link_lost(&mut self, lost: bool) {
        self.can.link_lost = lost;
    }

    /// Makes the peripheral refuse (or take again) every frame.
    pub fn set_refusing(&mut self, refuse: bool) {
        self.can.refuse = refuse;
    }

    /// The frames the peripheral took, by period.
    pub fn sent(&self) -> &[Vec<CanFrame>] {
        &self.can.sent
    }

    /// The frames of the last period.
    pub fn last_period(&self) -> &[CanFrame] {
        self.can.sent.last().map(Vec::as_slice).unwrap_or(&[])
    }

    /// The legs as the simulated joints really are.
    pub fn true_legs(&self) -> LegConfig {
        self.axes
            .true_legs(&self.robot.can, &self.robot.geometry)
            .unwrap()
    }

    /// Sum of the simulated wheels' absolute speeds, turns/s.
    pub fn wheel_speed_sum(&self) -> f32 {
        wheelleg_firmware_sim::rig::true_wheel_speed_sum(&self.axes)
    }
}

impl Board for SimBoard {
    type Frame = CanFrame;
    type Can = SimCan;

    fn can(&mut self) -> &mut SimCan {
        &mut self.can
    }

    /// The motors run for the period that ended (none before the first), then the new one
    /// begins: the rig's order, so the loop reads what the axes sent in the last period.
    fn wait_for_tick(&mut self) {
        if self.periods > 0 {
            let dt_s = PHYSICS_US as f32 * 1e-6;
            for _ in 0..PERIOD_US / PHYSICS_US {
                self.now_us += PHYSICS_US;
                self.axes
                    .run(&mut self.axes_port, self.now_us, dt_s)
                    .unwrap();
            }
        }
        self.periods += 1;
        self.can.now_us = self.now_us;
        self.can.sent.push(Vec::new());
    }

    fn link_lost(&self) -> bool {
        self.can.link_lost
    }
}

/// Runs periods until the activity in progress ends, at most `limit`: how many periods it took
/// and how it ended. Every period before the last finishes nothing and leaves the loop busy.
pub fn run_until_finished(
    control: &mut Control<CanFrame>,
    board: &mut SimBoard,
    limit: u32,
) -> (u32, Finished) {
    for period in 1..=limit {
        assert!(control.busy(), "idle before anything finished");
        if let Some(finished) = control.period(board) {
            assert!(!control.busy(), "{finished:?} ended, yet still busy");
            return (period, finished);
        }
    }
    panic!("nothing finished in {limit} periods");
}

/// The loop and its board after a successful start-up, legs at `start`.
pub fn started_at(start: LegConfig) -> (Control<CanFrame>, SimBoard) {
    let robot = robot();
    let mut board = SimBoard::new(&robot, start);
    let mut control = Control::new(&robot, start);
    control.begin_start_up();
    let (_, finished) = run_until_finished(&mut control, &mut board, 100);
    assert_eq!(finished, Finished::StartUp(Ok(())));
    (control, board)
}

/// [`started_at`] the default legs.
pub fn started() -> (Control<CanFrame>, SimBoard) {
    started_at(start_legs())
}

/// Setpoints of a step or retreat under the loop's motion settings.
pub fn setpoints_per_motion() -> u32 {
    let config = MotionConfig::default();
    (config.control_rate_hz * config.step_duration_s).round() as u32
}

/// Periods of settling after a motion's setpoints.
pub fn settle_periods() -> u32 {
    (SETTLE_S * MotionConfig::default().control_rate_hz).round() as u32
}

/// The frames the loop sends for `setpoint`, in its order.
pub fn frames_of(robot: &Robot, setpoint: &Setpoint) -> Vec<CanFrame> {
    let mut queue: TxQueue<CanFrame, TX_FRAMES> = TxQueue::new();
    Commander::new(robot.can)
        .queue_setpoint(&mut queue, setpoint)
        .unwrap();
    std::iter::from_fn(|| queue.pop()).collect()
}

/// The frames of holding `legs`, wheels stopped.
pub fn hold_frames(robot: &Robot, legs: LegConfig) -> Vec<CanFrame> {
    frames_of(robot, &Setpoint::hold(&robot.geometry, legs).unwrap())
}

/// The step the loop plans for `action` from `legs`.
pub fn plan(robot: &Robot, legs: LegConfig, action: Action) -> Result<StepMotion, ControlError> {
    Ok(StepMotion::plan(
        robot,
        &MotionConfig::default(),
        legs,
        action,
    )?)
}

/// Each frame's axis and message.
pub fn decoded(robot: &Robot, frames: &[CanFrame]) -> Vec<(Axis, Message)> {
    frames
        .iter()
        .map(|frame| {
            let (node, message) = decode(frame).unwrap();
            (robot.can.axis_on(node).unwrap(), message)
        })
        .collect()
}
