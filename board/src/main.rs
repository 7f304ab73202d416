//! The controller firmware on a NUCLEO-G474RE (STM32G474RE): the QEMU image's program
//! (`controller/src/production/`) on the part's own peripherals, with the control period
//! moved into an interrupt above the decision.
//!
//! - Boot: the clocks (170 MHz from the HSE), the boot check of the weights
//!   ([`Stack::new`]), FDCAN1, the observation link on USART2, then the control period's
//!   executor.
//! - The control period ([`period`]): every 10 ms, in an interrupt executor above thread mode,
//!   [`wheelleg_controller::control::Control::period`] on FDCAN1 (`board::can`): the start-up,
//!   a step's setpoints and settling, and between them the pose held.
//! - The decision (thread mode): observations in on the observation link, inference, the
//!   decision rule, the guard and the arrival rule, the decision out; then the step handed to
//!   the control period and its end reported. However long a decision takes, the periods run.
//!
//! The link's messages and the safe stop's rules are the QEMU image's (docs/controller.md): a
//! decision has [`DECISION_DEADLINE_MS`] from its fine window's arrival, past which it is
//! abandoned and the host told; an observation link silent (or only corrupt) for
//! [`OBSERVATION_TIMEOUT`] between steps puts the robot in safe stop. defmt (over RTT, read by
//! probe-rs) logs the start-up and faults only, nothing on the data path.
#![no_std]
#![no_main]

mod board;
mod period;

use core::mem::MaybeUninit;

use defmt_rtt as _;
use embassy_executor::{InterruptExecutor, Spawner};
use embassy_stm32::interrupt;
use embassy_stm32::interrupt::InterruptExt;
use embassy_time::{Duration, Instant, Timer};
use panic_probe as _;
use wheelleg_controller::control::{ControlError, Stop, StopReason};
use wheelleg_controller::link::Buffer;
use wheelleg_controller::report::stop_report;
use wheelleg_controller::stack::{
    ControllerDecider, DecisionRecord, Observation, Stack, StackError, DECISION_DEADLINE_MS,
    ROW_ELEMENTS, WORK_BYTES,
};
use wheelleg_controller::wire::{self, FromController, ToController, WireError};
use wheelleg_runtime::can::host::RollCallProblem;
use wheelleg_runtime::model::Outputs;

use board::can::{Fdcan, FdcanBoard};
use board::link::{ObservationLink, Received};
use period::{stop_state, Command, DecisionSide, Ended};

/// Time without a valid frame on the observation link, between steps, before the safe stop:
/// the QEMU image's 100 periods (the perception computer answers within a period; the longest
/// frame, the fine window's 10.6 KB, takes 0.05 s at 2 Mbit/s).
const OBSERVATION_TIMEOUT: Duration = Duration::from_millis(1_000);
/// How long one wait on the link lasts before the timeout is looked at again.
const LINK_WAIT: Duration = Duration::from_millis(10);
/// How often the decision side looks for the end of the activity it handed over.
const ENDED_POLL: Duration = Duration::from_millis(1);

/// The policy's weights (weights/policy.wlw, or the file WHEELLEG_WEIGHTS named at build:
/// build.rs), in flash, word-aligned so that the kernels may load 4 weights at once.
#[repr(C, align(4))]
struct Aligned<T: ?Sized>(T);
static WEIGHTS: &Aligned<[u8]> = &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/policy.wlw")));

static WORK: Buffer<[i8; WORK_BYTES]> = Buffer::new([0; WORK_BYTES]);
static ROW: Buffer<[i16; ROW_ELEMENTS]> = Buffer::new([0; ROW_ELEMENTS]);
static OBSERVATION: Buffer<Observation> = Buffer::new(Observation::new());
static DECIDER: Buffer<ControllerDecider> = Buffer::new(ControllerDecider::new());
/// In `.uninit`: neither zeroed at start-up nor given initial bytes in flash (the boot check
/// writes it).
#[link_section = ".uninit.STACK"]
static STACK: Buffer<MaybeUninit<Stack<'static, 'static>>> = Buffer::new(MaybeUninit::uninit());

/// The control period's executor, run by [`board::CONTROL_INTERRUPT`].
static CONTROL_EXECUTOR: InterruptExecutor = InterruptExecutor::new();

#[interrupt]
unsafe fn UART5() {
    // SAFETY: UART5 is the control executor's interrupt (board::CONTROL_INTERRUPT), unmasked
    // by its start, and nothing else runs it.
    unsafe { CONTROL_EXECUTOR.on_interrupt() }
}

/// Stops the decision side for good (a failed boot check, inference failing). The control
/// period, if it runs, keeps the robot held, in safe stop once asked.
fn halt() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

/// The report after a step (or a retreat): its end, or the safe stop it ended in.
fn step_report(ended: &Ended) -> FromController {
    let report = ended.report;
    match report.stop {
        Some(stop) => stop_report(stop),
        None => FromController::StepDone {
            moved: ended.moved,
            pose: report.pose,
            legs_m: report.legs_m,
            tick: report.tick,
        },
    }
}

/// The decision record as the link's message.
fn decision(record: &DecisionRecord) -> FromController {
    FromController::Decision {
        logits: record.logits,
        greedy: record.greedy,
        greedy_verdict: record.greedy_verdict,
        action: record.action,
        level: record.level,
        checks: record.checks,
    }
}

/// The work area's bytes: a frame arrives there, and inference then reuses them.
fn bytes(work: &mut [i8; WORK_BYTES]) -> &mut [u8; WORK_BYTES] {
    // SAFETY: `i8` and `u8` have the same size, alignment and validity.
    unsafe { &mut *(work as *mut [i8; WORK_BYTES] as *mut [u8; WORK_BYTES]) }
}

/// Hands `command` to the control period (its queue has room: one command is in flight at
/// most, so this waits only in theory).
async fn command(side: &mut DecisionSide, command: Command) {
    while side.commands.enqueue(command).is_err() {
        Timer::after(ENDED_POLL).await;
    }
}

/// Hands `command` over and waits for the end of the activity it begins.
async fn run_activity(side: &mut DecisionSide, activity: Command) -> Ended {
    command(side, activity).await;
    loop {
        if let Some(ended) = side.ended.dequeue() {
            return ended;
        }
        Timer::after(ENDED_POLL).await;
    }
}

/// Puts the robot in safe stop for `reason` and waits for the period that does it.
async fn stop_now(side: &mut DecisionSide, reason: StopReason) -> Stop {
    command(side, Command::Stop(reason)).await;
    loop {
        if let Some(stop) = stop_state() {
            return stop;
        }
        Timer::after(ENDED_POLL).await;
    }
}

/// Logs a safe stop once (a fault: the one kind of log line after the start-up).
fn log_stop(stop: Stop, logged: &mut bool) {
    if !core::mem::replace(logged, true) {
        if let FromController::Stopped { reason, axes, tick } = stop_report(stop) {
            defmt::warn!(
                "safe stop: reason {=u8}, axes {=u16:#06x}, period {=u32}",
                reason,
                axes,
                tick
            );
        }
    }
}

/// Logs why the start-up failed: the roll call's refusal names the node to look at.
fn log_start_up_failure(error: Option<ControlError>) {
    match error {
        Some(ControlError::StartupRefused(refusal)) => {
            let problem = match refusal.problem {
                RollCallProblem::Missing => "missing: nothing heard from it",
                RollCallProblem::TwoDevices => "two devices share this node id",
                RollCallProblem::UnsupportedFirmware(_) => "firmware other than 0.5.x",
            };
            defmt::error!(
                "start-up refused, nothing armed: node {=u8}: {=str}",
                refusal.node.get(),
                problem
            );
        }
        Some(ControlError::StartupFailed) => {
            defmt::error!("start-up failed: not every axis reported closed loop without errors")
        }
        _ => defmt::error!("start-up failed: a frame could not be queued or sent"),
    }
}

#[embassy_executor::main]
async fn main(_spawner: Spawner) {
    let p = embassy_stm32::init(board::config());
    if let Some(core) = cortex_m::Peripherals::take() {
        board::start_cycle_counter(core);
    }
    defmt::info!("wheelleg board: STM32G474RE at {=u32} Hz", board::SYSCLK_HZ);
    let (Some(decider), Some(slot), Some(work), Some(row), Some(observation)) = (
        DECIDER.take(),
        STACK.take(),
        WORK.take(),
        ROW.take(),
        OBSERVATION.take(),
    ) else {
        halt()
    };
    let Ok(stack) = Stack::new(&WEIGHTS.0, decider) else {
        defmt::error!("boot check: the weights file is refused; nothing runs");
        halt()
    };
    let stack = slot.write(stack);
    defmt::info!(
        "boot check: weights accepted ({=usize} bytes)",
        WEIGHTS.0.len()
    );
    let Some(can) = Fdcan::new(p.FDCAN1, p.PA11, p.PA12) else {
        halt()
    };
    let Some(mut link) = ObservationLink::new(p.USART2, p.PA3, p.PA2, p.DMA1_CH1, p.DMA1_CH2)
    else {
        defmt::error!("USART2 refused its configuration");
        halt()
    };
    board::set_priorities();
    let Some((mut side, period_side)) = period::queues() else {
        halt()
    };
    board::CONTROL_INTERRUPT.set_priority(board::CONTROL_PRIORITY);
    let control = CONTROL_EXECUTOR.start(board::CONTROL_INTERRUPT);
    match period::run(FdcanBoard::new(can), stack.robot(), period_side) {
        Ok(task) => control.spawn(task),
        Err(_) => halt(),
    }
    defmt::info!(
        "ready: observation link on USART2 at {=u32} bit/s, ODrive bus on FDCAN1 at 1 Mbit/s",
        board::link::BAUD_RATE
    );

    // The axes are started up with the first decision, where the legs stand as its
    // observation says.
    let mut started = false;
    // The policy's outputs on the observation whose window is awaited.
    let mut pending: Option<Outputs> = None;
    // The bring-up test's slowness for the next decision.
    let mut delay = Duration::from_ticks(0);
    let (mut quiet_since, mut corrupt, mut answered) = (Instant::now(), false, true);
    let mut stop_logged = false;
    loop {
        // The link's silence counts from the controller's last answer to a valid frame.
        if core::mem::take(&mut answered) {
            quiet_since = Instant::now();
        }
        let received = link.receive(bytes(work), LINK_WAIT).await;
        if started && stop_state().is_none() && quiet_since.elapsed() >= OBSERVATION_TIMEOUT {
            let reason = if corrupt {
                StopReason::ObservationCorrupt
            } else {
                StopReason::ObservationStalled
            };
            let stop = stop_now(&mut side, reason).await;
            log_stop(stop, &mut stop_logged);
            link.send(stop_report(stop)).await;
        }
        let len = match received {
            Received::Quiet => continue,
            Received::Bad => Err(WireError::Framing),
            Received::Frame(len) => Ok(len),
        };
        let message =
            len.and_then(|len| wire::open::<ToController>(bytes(work).get(..len).unwrap_or(&[])));
        let message = match message {
            Ok(message) => message,
            Err(error) => {
                corrupt = true;
                link.send(FromController::Rejected {
                    error: error.code(),
                })
                .await;
                continue;
            }
        };
        (answered, corrupt) = (true, false);
        if let Some(stop) = stop_state() {
            log_stop(stop, &mut stop_logged);
            link.send(stop_report(stop)).await;
            continue;
        }
        match (message, pending.take()) {
            (
                ToController::Observation {
                    new_episode,
                    height_mm_le,
                    state_mm,
                },
                _,
            ) => {
                if !observation.read(height_mm_le, state_mm) {
                    link.send(FromController::Rejected {
                        error: WireError::Message.code(),
                    })
                    .await;
                    continue;
                }
                if new_episode {
                    stack.reset();
                }
                let Ok(outputs) = stack.infer(observation, work, row) else {
                    defmt::error!("inference failed; the decision side stops");
                    if started {
                        stop_now(&mut side, StopReason::Control).await;
                    }
                    halt()
                };
                pending = Some(outputs);
                link.send(FromController::WindowPlease).await;
            }
            (ToController::Window { heights_mm_le }, Some(outputs)) => {
                let began = Instant::now();
                let deadline = began + Duration::from_millis(u64::from(DECISION_DEADLINE_MS));
                // The bring-up test's slow decision: busy, as a decision is, while the
                // control period holds the robot.
                let delayed = began + core::mem::replace(&mut delay, Duration::from_ticks(0));
                while Instant::now() < delayed {}
                let decided = stack.decide_in_time(observation, &outputs, heights_mm_le, || {
                    Instant::now() < deadline
                });
                let record = match decided {
                    Ok(record) => record,
                    Err(StackError::DeadlineMissed) => {
                        let periods = began.elapsed().as_ticks() / period::period().as_ticks();
                        link.send(FromController::DeadlineMissed {
                            periods: u32::try_from(periods).unwrap_or(u32::MAX),
                        })
                        .await;
                        continue;
                    }
                    Err(_) => {
                        link.send(FromController::Rejected {
                            error: WireError::Message.code(),
                        })
                        .await;
                        continue;
                    }
                };
                link.send(decision(&record)).await;
                let mut report = None;
                if !started {
                    started = true;
                    let legs = observation.legs();
                    let start_up = run_activity(&mut side, Command::StartUp { legs }).await;
                    match start_up.report.stop {
                        Some(stop) => {
                            log_start_up_failure(start_up.error);
                            log_stop(stop, &mut stop_logged);
                            report = Some(stop_report(stop));
                        }
                        None => defmt::info!("start-up: every axis in closed loop"),
                    }
                }
                let report = match report {
                    Some(report) => report,
                    None => {
                        let step = Command::Step(record.action());
                        step_report(&run_activity(&mut side, step).await)
                    }
                };
                link.send(report).await;
            }
            (ToController::Collided, None) => {
                if started {
                    let ended = run_activity(&mut side, Command::Retreat).await;
                    link.send(step_report(&ended)).await;
                }
            }
            (ToController::DelayNextDecision { ms }, outputs) => {
                pending = outputs;
                delay = Duration::from_millis(u64::from(ms));
            }
            _ => {
                link.send(FromController::Rejected {
                    error: WireError::Message.code(),
                })
                .await
            }
        }
    }
}
