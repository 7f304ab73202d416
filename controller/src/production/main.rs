//! The production image on QEMU's mps2-an386 (Cortex-M4F): what flash is measured on. Boots,
//! checks the weights file, then decides and drives, with none of the check harness
//! (semihosting, replay, counts, the scalar kernel's comparison: `src/check/main.rs`). The board's
//! parts in `board.rs`, the observation link in `observation_link.rs`.
//!
//! Its links are a real robot's: the observation link from the perception computer on CMSDK
//! UART 1 (COBS-framed, CRC-checked `postcard` messages: `wire`), and an SLCAN (Lawicel) CAN
//! adapter on UART 2 with the ODrive bus behind it (`board.rs`).
//!
//! Two priorities: the 100 Hz control period runs in SysTick's interrupt (`period.rs`), above
//! the decision, which runs here in thread mode; so every period holds the robot, or streams
//! its step, however long the core decides. A decision has [`DECISION_DEADLINE_MS`] from its
//! fine window's arrival; past it, it is abandoned and the host told. An observation link
//! silent (or only corrupt) for [`OBSERVATION_TIMEOUT_PERIODS`] between steps puts the robot
//! in safe stop. A board's HAL puts its FDCAN driver and timer in place of the adapter and
//! SysTick (docs/controller.md).
#![no_std]
#![no_main]

mod board;
mod observation_link;
mod period;

use core::arch::asm;
use core::mem::MaybeUninit;
use core::panic::PanicInfo;
use core::sync::atomic::Ordering;

use cortex_m_rt::entry;
use wheelleg_controller::control::StopReason;
use wheelleg_controller::link::Buffer;
use wheelleg_controller::report::stop_report;
use wheelleg_controller::stack::{
    ControllerDecider, DecisionRecord, Observation, Stack, StackError, DECISION_DEADLINE_MS,
    ROW_ELEMENTS, WORK_BYTES,
};
use wheelleg_controller::wire::{self, FromController, ToController, WireError};
use wheelleg_runtime::model::Outputs;

use board::{sleep_unless, SlcanBoard, Uart};
use observation_link::{reached, Link, Received};
use period::{Command, Done, PERIODS};

/// Control periods without a valid frame on the observation link, between steps, before the
/// safe stop: 1 s (the perception computer answers within a period; the longest frame, the
/// fine window's 10.6 KB, takes 0.05 s at 2 Mbit/s).
const OBSERVATION_TIMEOUT_PERIODS: u32 = 100;

/// [`DECISION_DEADLINE_MS`] in control periods (10 ms each).
const DECISION_DEADLINE_PERIODS: u32 = DECISION_DEADLINE_MS.div_ceil(10);

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

/// Interrupts of the vector table, up to the one enabled: UART 2's receiver (the CAN
/// adapter's bytes). SysTick is an exception; the observation link is polled.
#[link_section = ".vector_table.interrupts"]
#[no_mangle]
static __INTERRUPTS: [unsafe extern "C" fn(); board::UART2_RX_IRQ + 1] = [
    unused_interrupt,
    unused_interrupt,
    unused_interrupt,
    unused_interrupt,
    board::uart2_rx,
];

/// An interrupt nothing enabled: stop here.
unsafe extern "C" fn unused_interrupt() {
    halt()
}

/// Stops the core (an unused interrupt, a panic, a failed boot check).
fn halt() -> ! {
    loop {
        // SAFETY: `wfi` only waits for an interrupt.
        unsafe { asm!("wfi", options(nomem, nostack)) };
    }
}

#[panic_handler]
fn panic(_info: &PanicInfo) -> ! {
    halt()
}

/// Waits until the control period reports the end of the activity it was given.
fn wait_done() -> Done {
    loop {
        if let Some(done) = period::take_done() {
            return done;
        }
        sleep_unless(|| false);
    }
}

/// Runs `command` through the control period and waits for the report of its end.
fn drive(command: Command) -> FromController {
    period::post(command);
    loop {
        if let Done::Step(report) = wait_done() {
            return report;
        }
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

#[entry]
fn main() -> ! {
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
        halt()
    };
    let stack = slot.write(stack);
    let mut link = Link {
        uart: Uart::new(Uart::UART1),
        frames: wire::FrameReceiver::new(),
    };
    let Some(board) = SlcanBoard::start(Uart::new(Uart::UART2)) else {
        halt()
    };
    if !period::hand_over(board, stack.robot()) {
        halt()
    }
    // The legs start where the first observation says they are: the control period takes
    // the robot over at the first decision.
    let mut started = false;
    // The policy's outputs on the observation whose window is awaited.
    let mut pending: Option<Outputs> = None;
    let mut delay_periods = 0u32;
    let (mut quiet_since, mut corrupt, mut answered) = (0, false, true);
    loop {
        // The link's silence counts from the controller's last answer to a valid frame.
        if core::mem::take(&mut answered) {
            quiet_since = PERIODS.load(Ordering::Relaxed);
        }
        let watched = started && period::stopped().is_none();
        let until = watched.then(|| quiet_since.wrapping_add(OBSERVATION_TIMEOUT_PERIODS));
        let len = match link.receive(bytes(work), until) {
            Received::TimedOut => {
                period::post(Command::Stop(if corrupt {
                    StopReason::ObservationCorrupt
                } else {
                    StopReason::ObservationStalled
                }));
                let stop = loop {
                    if let Some(stop) = period::stopped() {
                        break stop;
                    }
                    sleep_unless(|| false);
                };
                link.send(stop_report(stop));
                continue;
            }
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
                });
                continue;
            }
        };
        (answered, corrupt) = (true, false);
        if let Some(stop) = period::stopped() {
            link.send(stop_report(stop));
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
                    });
                    continue;
                }
                if new_episode {
                    stack.reset();
                }
                let Ok(outputs) = stack.infer(observation, work, row) else {
                    halt()
                };
                pending = Some(outputs);
                link.send(FromController::WindowPlease);
            }
            (ToController::Window { heights_mm_le }, Some(outputs)) => {
                let began = PERIODS.load(Ordering::Relaxed);
                let deadline = began.wrapping_add(DECISION_DEADLINE_PERIODS);
                // The bring-up test's slow decision: busy, as a decision is.
                let delayed = began.wrapping_add(core::mem::take(&mut delay_periods));
                while !reached(delayed) {}
                let decided = stack
                    .decide_in_time(observation, &outputs, heights_mm_le, || !reached(deadline));
                let record = match decided {
                    Ok(record) => record,
                    Err(StackError::DeadlineMissed) => {
                        let periods = PERIODS.load(Ordering::Relaxed).wrapping_sub(began);
                        link.send(FromController::DeadlineMissed { periods });
                        continue;
                    }
                    Err(_) => {
                        link.send(FromController::Rejected {
                            error: WireError::Message.code(),
                        });
                        continue;
                    }
                };
                link.send(decision(&record));
                if !started {
                    started = true;
                    period::post(Command::Start {
                        legs: observation.legs(),
                    });
                    wait_done();
                }
                link.send(drive(Command::Step(record.action())));
            }
            (ToController::Collided, None) => {
                if started {
                    link.send(drive(Command::Retreat));
                }
            }
            (ToController::DelayNextDecision { ms }, outputs) => {
                pending = outputs;
                delay_periods = ms.div_ceil(10);
            }
            _ => link.send(FromController::Rejected {
                error: WireError::Message.code(),
            }),
        }
    }
}
