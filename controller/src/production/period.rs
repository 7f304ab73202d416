//! The control period in SysTick's interrupt, above the decision: every 10 ms it runs one
//! period of the control loop (`Control::period`) whatever the decision in thread mode is
//! doing, so the robot is held, or its step streamed, while the core decides.
//!
//! The decision side talks to it through three cells behind critical sections (a few words
//! each, so the period is never held back long): the command it posts (start up, step,
//! retreat, stop), the report of the activity that ended, and the safe stop the period is in.
//! The board and the control loop belong to the interrupt alone once handed over.

use core::cell::{Cell, RefCell};
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::interrupt::{self, Mutex};
use cortex_m_rt::exception;
use wheelleg_controller::control::{Control, Finished, Stop, StopReason};
use wheelleg_controller::link::Buffer;
use wheelleg_controller::report::step_report;
use wheelleg_controller::wire::FromController;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::Robot;

use crate::board::SlcanBoard;

/// What the decision asks of the control period.
pub(crate) enum Command {
    /// Take over the robot with its legs at `legs`, and start it up.
    Start { legs: LegConfig },
    /// Drive one decision's step.
    Step(Action),
    /// Back out of the last step.
    Retreat,
    /// Hold the robot in safe stop.
    Stop(StopReason),
}

/// An activity the period finished, for the decision side.
#[derive(Clone, Copy)]
pub(crate) enum Done {
    /// The start-up ended (in safe stop if it failed).
    StartUp,
    /// A step or a retreat ended: its report for the host.
    Step(FromController),
}

/// Control periods since SysTick started, the decision's clock (its deadline, the
/// observation link's timeout). Counted even before the robot is taken over.
pub(crate) static PERIODS: AtomicU32 = AtomicU32::new(0);

/// The control period's state, in `.uninit` (written once at the hand-over; a `None` of it
/// would take flash for its initial bytes).
#[link_section = ".uninit.PERIOD"]
static PERIOD_STATE: Buffer<MaybeUninit<Period>> = Buffer::new(MaybeUninit::uninit());
static HANDOVER: Mutex<RefCell<Option<&'static mut Period>>> = Mutex::new(RefCell::new(None));
static COMMAND: Mutex<Cell<Option<Command>>> = Mutex::new(Cell::new(None));
static DONE: Mutex<Cell<Option<Done>>> = Mutex::new(Cell::new(None));
static STOPPED: Mutex<Cell<Option<Stop>>> = Mutex::new(Cell::new(None));

/// Hands the board and the robot it drives to the control period (before SysTick's first
/// interrupt can use them); false if called twice.
pub(crate) fn hand_over(board: SlcanBoard, robot: Robot) -> bool {
    let Some(slot) = PERIOD_STATE.take() else {
        return false;
    };
    let period = slot.write(Period {
        board,
        robot,
        control: None,
    });
    interrupt::free(|cs| HANDOVER.borrow(cs).replace(Some(period)));
    true
}

/// Posts `command` for the next period (replacing one not yet taken: the decision side posts
/// one at a time and waits for its end).
pub(crate) fn post(command: Command) {
    interrupt::free(|cs| COMMAND.borrow(cs).set(Some(command)));
}

/// The activity that ended since the last asking.
pub(crate) fn take_done() -> Option<Done> {
    interrupt::free(|cs| DONE.borrow(cs).take())
}

/// The safe stop the robot is in, as of the last period.
pub(crate) fn stopped() -> Option<Stop> {
    interrupt::free(|cs| STOPPED.borrow(cs).get())
}

/// The control period's own state: the board, the robot, and the loop once the robot is taken
/// over.
struct Period {
    board: SlcanBoard,
    robot: Robot,
    control: Option<Control<CanFrame>>,
}

#[exception]
fn SysTick() {
    static mut PERIOD: Option<&'static mut Period> = None;
    PERIODS.fetch_add(1, Ordering::Relaxed);
    if PERIOD.is_none() {
        *PERIOD = interrupt::free(|cs| HANDOVER.borrow(cs).take());
    }
    let Some(period) = PERIOD.as_deref_mut() else {
        return;
    };
    let command = interrupt::free(|cs| COMMAND.borrow(cs).take());
    let done = period.run(command);
    let stop = period.control.as_ref().and_then(Control::stop_state);
    interrupt::free(|cs| {
        if done.is_some() {
            DONE.borrow(cs).set(done);
        }
        STOPPED.borrow(cs).set(stop);
    });
}

impl Period {
    /// Runs this period, then takes `command` (none before the robot is taken over: the
    /// adapter hears nothing until the first step). A command begins after the period's
    /// frames are out, so that its set-up (a step's motion plan) never delays them; its first
    /// setpoint goes out in the next period.
    fn run(&mut self, command: Option<Command>) -> Option<Done> {
        let mut done = None;
        if let Some(control) = self.control.as_mut() {
            done = match control.period(&mut self.board) {
                Some(Finished::StartUp(_)) => Some(Done::StartUp),
                Some(Finished::Step(result)) => Some(Done::Step(step_report(control, result))),
                None => None,
            };
        }
        match command {
            Some(Command::Start { legs }) => {
                self.control
                    .insert(Control::new(&self.robot, legs))
                    .begin_start_up();
            }
            Some(Command::Step(action)) => {
                if let Some(control) = self.control.as_mut() {
                    let begun = if control.stopped() {
                        Ok(())
                    } else {
                        control.begin_step(action)
                    };
                    if begun.is_err() || !control.busy() {
                        done = Some(Done::Step(step_report(control, begun)));
                    }
                }
            }
            Some(Command::Retreat) => {
                if let Some(control) = self.control.as_mut() {
                    let begun = control.begin_retreat();
                    if begun.is_err() || !control.busy() {
                        done = Some(Done::Step(step_report(control, begun)));
                    }
                }
            }
            Some(Command::Stop(reason)) => {
                if let Some(control) = self.control.as_mut() {
                    control.stop(reason);
                }
            }
            None => {}
        }
        done
    }
}
