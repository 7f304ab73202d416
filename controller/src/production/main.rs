//! The production image on QEMU's mps2-an386 (Cortex-M4F): what flash is measured on. Boots,
//! checks the weights file, then decides and drives, with none of the check harness
//! (semihosting, replay, counts, the scalar kernel's comparison: `src/check/main.rs`). The board's
//! parts in `board.rs`, the observation link in `observation_link.rs`.
//!
//! Its links are a real robot's: the observation link from the perception computer on CMSDK
//! UART 1 (COBS-framed, CRC-checked `postcard` messages: `wire`), and an SLCAN (Lawicel) CAN
//! adapter on UART 2 with the ODrive bus behind it; SysTick paces the 100 Hz period. Each
//! period starts with the adapter's status poll (`F`), whose answer ends the period's
//! received frames; an adapter that stops answering is a lost CAN link. Between steps the
//! robot is held, and an observation link silent (or only corrupt) for
//! [`OBSERVATION_TIMEOUT_PERIODS`] puts it in safe stop. A board's HAL puts its FDCAN driver
//! and timer in place of the adapter and SysTick (docs/controller.md).
#![no_std]
#![no_main]

mod board;
mod observation_link;

use core::arch::asm;
use core::mem::MaybeUninit;
use core::panic::PanicInfo;

use cortex_m_rt::entry;
use wheelleg_controller::control::{Control, ControlError, StopReason};
use wheelleg_controller::link::Buffer;
use wheelleg_controller::stack::{
    ControllerDecider, DecisionRecord, Observation, Stack, ROW_ELEMENTS, WORK_BYTES,
};
use wheelleg_controller::wire::{self, stop_reason, FromController, ToController, WireError};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::model::Outputs;

use board::{SlcanBoard, Uart};
use observation_link::{Link, Received};

/// Control periods without a valid frame on the observation link, between steps, before the
/// safe stop: 1 s (the perception computer answers within a period; the longest frame, the
/// fine window's 10.6 KB, takes 0.05 s at 2 Mbit/s).
const OBSERVATION_TIMEOUT_PERIODS: u32 = 100;

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

/// Interrupts of the vector table: none is enabled (the controller polls its UARTs, and
/// SysTick is an exception), so the table has only the one entry cortex-m-rt's link script
/// asks for; an interrupt that fired anyway would find no handler past it.
#[link_section = ".vector_table.interrupts"]
#[no_mangle]
static __INTERRUPTS: [unsafe extern "C" fn(); 1] = [unused_interrupt];

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

/// The report of a stopped controller.
fn stopped(control: &Control<CanFrame>) -> Option<FromController> {
    let stop = control.stop_state()?;
    let (reason, axes) = match stop.reason {
        StopReason::Silent(axes) => (stop_reason::SILENT_AXES, axes.0),
        StopReason::AxisError(axes) => (stop_reason::AXIS_ERRORS, axes.0),
        StopReason::CanLink => (stop_reason::CAN_LINK, 0),
        StopReason::ObservationStalled => (stop_reason::OBSERVATION_STALLED, 0),
        StopReason::ObservationCorrupt => (stop_reason::OBSERVATION_CORRUPT, 0),
        StopReason::StartupFailed => (stop_reason::STARTUP_FAILED, 0),
        StopReason::Control => (stop_reason::CONTROL, 0),
    };
    Some(FromController::Stopped {
        reason,
        axes,
        tick: stop.tick,
    })
}

/// The report after a step (or a retreat): its end, or the safe stop it ended in.
fn step_report(
    control: &mut Control<CanFrame>,
    driven: Result<(), ControlError>,
) -> FromController {
    let moved = match driven {
        Ok(()) => true,
        // Legs out of reach: nothing was sent, as on the host.
        Err(ControlError::Motion(_)) => false,
        Err(_) => {
            control.stop(StopReason::Control);
            true
        }
    };
    if let Some(report) = stopped(control) {
        return report;
    }
    let pose = control.odometry().pose;
    let legs = control.measured_legs().unwrap_or(control.legs());
    FromController::StepDone {
        moved,
        pose: [
            pose.translation.x,
            pose.translation.y,
            pose.rotation.angle(),
        ],
        legs_m: [legs.clearance_m, legs.track_m],
        tick: control.ticks(),
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
        cobs: cobs::DecoderState::Idle,
        len: 0,
        too_long: false,
    };
    let mut board = SlcanBoard::new(Uart::new(Uart::UART2));
    // The legs start where the first observation says they are.
    let mut control: Option<Control<CanFrame>> = None;
    // The policy's outputs on the observation whose window is awaited.
    let mut pending: Option<Outputs> = None;
    let (mut quiet_periods, mut corrupt) = (0u32, false);
    loop {
        let len = match link.receive(bytes(work), &mut board, control.as_mut()) {
            Received::Period => {
                quiet_periods += 1;
                if let Some(control) = control.as_mut().filter(|c| !c.stopped()) {
                    if quiet_periods >= OBSERVATION_TIMEOUT_PERIODS {
                        control.stop(if corrupt {
                            StopReason::ObservationCorrupt
                        } else {
                            StopReason::ObservationStalled
                        });
                        if let Some(report) = stopped(control) {
                            link.send(report);
                        }
                    }
                }
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
        (quiet_periods, corrupt) = (0, false);
        if let Some(report) = control.as_ref().and_then(stopped) {
            link.send(report);
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
                if height_mm_le.len() != 2 * observation.height_mm.len() {
                    link.send(FromController::Rejected {
                        error: WireError::Message.code(),
                    });
                    continue;
                }
                for (cell, pair) in observation
                    .height_mm
                    .iter_mut()
                    .zip(height_mm_le.chunks_exact(2))
                {
                    *cell = i16::from_le_bytes([
                        pair.first().copied().unwrap_or(0),
                        pair.get(1).copied().unwrap_or(0),
                    ]);
                }
                observation.state_mm = state_mm;
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
                let Ok(record) = stack.decide(observation, &outputs, heights_mm_le) else {
                    link.send(FromController::Rejected {
                        error: WireError::Message.code(),
                    });
                    continue;
                };
                link.send(decision(&record));
                let control = match &mut control {
                    Some(control) => control,
                    empty => {
                        let started =
                            empty.insert(Control::new(&stack.robot(), observation.legs()));
                        if started.start_up(&mut board).is_err() {
                            started.stop(StopReason::StartupFailed);
                        }
                        started
                    }
                };
                let driven = if control.stopped() {
                    Ok(())
                } else {
                    control.step(&mut board, record.action())
                };
                link.send(step_report(control, driven));
            }
            (ToController::Collided, None) => {
                if let Some(control) = control.as_mut() {
                    let driven = control.retreat(&mut board);
                    link.send(step_report(control, driven));
                }
            }
            _ => link.send(FromController::Rejected {
                error: WireError::Message.code(),
            }),
        }
    }
}
