//! The 100 Hz control period, in an interrupt executor above the decision: every period runs
//! [`Control::period`] (feedback in, odometry, health, the current activity's frames out, the
//! pose held when there is none), however long the decision in thread mode takes.
//!
//! The decision side talks to it through two single-producer, single-consumer queues:
//! [`Command`]s in (start up, step, retreat, stop), taken at the start of a period, and one
//! [`Ended`] out for each activity begun, in the period it ends. The safe stop, once the loop
//! is in it, is also published in a cell ([`stop_state`]) that the decision side reads between
//! messages.

use core::cell::Cell;

use critical_section::Mutex;
use embassy_time::{Duration, Ticker};
use heapless::spsc::{Consumer, Producer, Queue};
use wheelleg_controller::control::{Control, ControlError, Stop, StopReason};
use wheelleg_controller::link::Buffer;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::MotionConfig;
use wheelleg_runtime::robot::Robot;

use crate::board::can::FdcanBoard;

/// Queue slots (one fewer than the queues' `N`): the decision side waits for each activity to
/// end before it begins another, so one command and one report are in flight at most.
const QUEUE_SLOTS: usize = 4;

/// What the decision side asks of the control period.
#[derive(Clone, Copy, Debug)]
pub enum Command {
    /// Take control with the legs at `legs` (the first observation's) and start the axes up:
    /// the roll call, Clear_Errors, arming.
    StartUp {
        /// The legs as the robot stands.
        legs: LegConfig,
    },
    /// Drive one decision's action, then settle.
    Step(Action),
    /// Back out of the last step (the world refused it).
    Retreat,
    /// Put the robot in safe stop.
    Stop(StopReason),
}

/// Where the robot is when an activity ends.
#[derive(Clone, Copy, Debug)]
pub struct Report {
    /// The safe stop, if the loop is in it.
    pub stop: Option<Stop>,
    /// Odometry since start-up: x, y in metres, yaw in radians.
    pub pose: [f32; 3],
    /// The measured legs (the commanded ones until every joint has reported): clearance,
    /// track in metres.
    pub legs_m: [f32; 2],
    /// Control periods since the start-up began.
    pub tick: u32,
}

/// An activity ended.
#[derive(Clone, Copy, Debug)]
pub struct Ended {
    /// False when the legs could not take the action: nothing was sent to the motors.
    pub moved: bool,
    /// Why the activity failed, if it did.
    pub error: Option<ControlError>,
    /// Where the robot is.
    pub report: Report,
}

/// The decision side's ends of the queues.
pub struct DecisionSide {
    /// Commands to the control period.
    pub commands: Producer<'static, Command>,
    /// Activities that ended.
    pub ended: Consumer<'static, Ended>,
}

/// The control period's ends of the queues.
pub struct PeriodSide {
    commands: Consumer<'static, Command>,
    ended: Producer<'static, Ended>,
}

static COMMANDS: Buffer<Queue<Command, QUEUE_SLOTS>> = Buffer::new(Queue::new());
static ENDED: Buffer<Queue<Ended, QUEUE_SLOTS>> = Buffer::new(Queue::new());
static STOP: Mutex<Cell<Option<Stop>>> = Mutex::new(Cell::new(None));

/// The queues between the two sides; `None` if called twice.
pub fn queues() -> Option<(DecisionSide, PeriodSide)> {
    let (commands_in, commands_out) = COMMANDS.take()?.split();
    let (ended_in, ended_out) = ENDED.take()?.split();
    Some((
        DecisionSide {
            commands: commands_in,
            ended: ended_out,
        },
        PeriodSide {
            commands: commands_out,
            ended: ended_in,
        },
    ))
}

/// The safe stop the control loop is in, as of the last period.
pub fn stop_state() -> Option<Stop> {
    critical_section::with(|cs| STOP.borrow(cs).get())
}

/// The activity whose end the decision side awaits.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Awaited {
    StartUp,
    Step,
}

/// The control period's length, from the runtime's control rate (10 ms at 100 Hz).
pub fn period() -> Duration {
    Duration::from_micros((1.0e6 / MotionConfig::default().control_rate_hz) as u64)
}

/// The control period: from the first [`Command::StartUp`] on, one [`Control::period`] every
/// period of the runtime's control rate, on the interrupt executor's priority.
#[embassy_executor::task]
pub async fn run(mut board: FdcanBoard, robot: Robot, mut side: PeriodSide) {
    // A late period is followed by the missed ones at once, so the loop's clock (its period
    // count) stays the wall clock the axes' timeouts run on.
    let mut ticker = Ticker::every(period());
    let mut control: Option<Control<CanFrame>> = None;
    let mut awaited: Option<Awaited> = None;
    loop {
        ticker.next().await;
        while let Some(command) = side.commands.dequeue() {
            match (command, control.as_mut()) {
                (Command::StartUp { legs }, None) => {
                    let started = control.insert(Control::new(&robot, legs));
                    started.begin_start_up();
                    awaited = Some(Awaited::StartUp);
                }
                (Command::Step(action), Some(control)) => {
                    let begun = control.begin_step(action);
                    awaited = begin(control, begun, &mut side.ended);
                }
                (Command::Retreat, Some(control)) => {
                    let begun = control.begin_retreat();
                    awaited = begin(control, begun, &mut side.ended);
                }
                (Command::Stop(reason), Some(control)) => control.stop(reason),
                // Nothing to stop, step or retreat before the start-up, and no second one.
                _ => {}
            }
        }
        let Some(control) = control.as_mut() else {
            continue;
        };
        let finished = control.period(&mut board);
        if let (Some(finished), Some(activity)) = (finished, awaited) {
            awaited = None;
            let result = finished.result();
            if activity == Awaited::StartUp && result.is_err() {
                control.stop(StopReason::StartupFailed);
            }
            let ended = ended(control, result);
            // The decision side has room: it awaits this one report.
            let _ = side.ended.enqueue(ended);
        }
        // A `Finished` with no activity awaited is a holding period's frame that could not be
        // queued: the loop has put itself in safe stop, which the cell below publishes.
        let stop = control.stop_state();
        critical_section::with(|cs| STOP.borrow(cs).set(stop));
    }
}

/// Starts awaiting the activity just begun, or reports at once the one that could not begin
/// (or, a retreat with no step to undo, had nothing to do).
fn begin(
    control: &mut Control<CanFrame>,
    begun: Result<(), ControlError>,
    ended_out: &mut Producer<'static, Ended>,
) -> Option<Awaited> {
    if begun.is_ok() && control.busy() {
        return Some(Awaited::Step);
    }
    let _ = ended_out.enqueue(ended(control, begun));
    None
}

/// The end of an activity with `result`, as the QEMU image reports it: legs out of reach moved
/// nothing; any other error stops the robot.
fn ended(control: &mut Control<CanFrame>, result: Result<(), ControlError>) -> Ended {
    let moved = match result {
        Ok(()) => true,
        Err(ControlError::Motion(_)) => false,
        Err(_) => {
            control.stop(StopReason::Control);
            true
        }
    };
    let pose = control.odometry().pose;
    let legs = control.measured_legs().unwrap_or(control.legs());
    Ended {
        moved,
        error: result.err(),
        report: Report {
            stop: control.stop_state(),
            pose: [
                pose.translation.x,
                pose.translation.y,
                pose.rotation.angle(),
            ],
            legs_m: [legs.clearance_m, legs.track_m],
            tick: control.ticks(),
        },
    }
}
