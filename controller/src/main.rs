//! The production image on QEMU's mps2-an386 (Cortex-M4F): what flash is measured on. Boots,
//! checks the weights file, then decides and drives, with none of the check harness
//! (semihosting, replay, counts, the scalar kernel's comparison: `src/check/main.rs`).
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

use core::arch::asm;
use core::mem::MaybeUninit;
use core::panic::PanicInfo;
use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use cortex_m_rt::{entry, exception};
use wheelleg_controller::control::{
    Board, Control, ControlError, StopReason, CAN_LINK_TIMEOUT_PERIODS,
};
use wheelleg_controller::link::Buffer;
use wheelleg_controller::stack::{
    ControllerDecider, DecisionRecord, Observation, Stack, ROW_ELEMENTS, WORK_BYTES,
};
use wheelleg_controller::wire::{self, stop_reason, FromController, ToController, WireError};
use wheelleg_runtime::can::slcan::{self, AdapterMessage, Decoder, Reply};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::model::Outputs;
use wheelleg_runtime::robot::WHEELLEG;

/// Control periods without a valid frame on the observation link, between steps, before the
/// safe stop: 1 s (the perception computer answers within a period; the longest frame, the
/// fine window's 10.6 KB, takes 0.05 s at 2 Mbit/s).
const OBSERVATION_TIMEOUT_PERIODS: u32 = 100;

/// The shipped weights, in flash, word-aligned so that the kernels may load 4 weights at once.
#[repr(C, align(4))]
struct Aligned<T: ?Sized>(T);
static WEIGHTS: &Aligned<[u8]> = &Aligned(*include_bytes!("../../weights/policy.wlw"));

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

/// A control period began and [`period_began`] has not yet said so.
static PERIOD_BEGAN: AtomicBool = AtomicBool::new(false);

/// SysTick's interrupt marks the period's start and wakes the core.
#[exception]
fn SysTick() {
    PERIOD_BEGAN.store(true, Ordering::Relaxed);
}

/// Sleeps until the next period's start unless it began already. Interrupts are masked from
/// the test to the `wfi`, so that a SysTick taken between them cannot leave the core asleep
/// through a whole period; `wfi` still wakes for a masked exception.
fn sleep_until_period() {
    // SAFETY: masking and unmasking interrupts, and `wfi`, touch no memory.
    unsafe { asm!("cpsid i", options(nomem, nostack)) };
    if !PERIOD_BEGAN.load(Ordering::Relaxed) {
        unsafe { asm!("wfi", options(nomem, nostack)) };
    }
    unsafe { asm!("cpsie i", options(nomem, nostack)) };
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

/// A CMSDK UART of mps2-an386, polled.
struct Uart(usize);

impl Uart {
    const UART1: usize = 0x4000_5000;
    const UART2: usize = 0x4000_6000;

    /// Enables the transmitter and the receiver.
    fn new(base: usize) -> Uart {
        // SAFETY: the CMSDK UART's registers (data, state, control, baud divider); writing
        // them has no effect on memory.
        unsafe {
            write_volatile((base + 0x10) as *mut u32, 16);
            write_volatile((base + 0x08) as *mut u32, 0b11);
        }
        Uart(base)
    }

    fn state(&self) -> u32 {
        // SAFETY: as in `new`: device registers.
        unsafe { read_volatile((self.0 + 0x04) as *const u32) }
    }

    /// Writes `bytes`, waiting while the transmit buffer is full.
    fn write(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            while self.state() & 1 != 0 {}
            // SAFETY: as in `new`.
            unsafe { write_volatile(self.0 as *mut u32, u32::from(byte)) };
        }
    }

    /// A received byte, if one is waiting.
    fn try_read(&mut self) -> Option<u8> {
        // SAFETY: as in `new`.
        (self.state() & 2 != 0).then(|| unsafe { read_volatile(self.0 as *const u32) } as u8)
    }
}

/// Whether a control period began since the last asking.
fn period_began() -> bool {
    PERIOD_BEGAN.swap(false, Ordering::Relaxed)
}

/// The CAN bus behind an SLCAN adapter on a UART: frames out as `t` lines, the adapter's frame
/// lines in, up to its answer to the period's status poll.
struct SlcanCan {
    uart: Uart,
    decoder: Decoder,
    /// The period's status poll is not answered yet: frames of the period may still come.
    polled: bool,
    /// Periods the poll has waited.
    waited: u32,
    /// A period began while waiting: the next one starts at once.
    period_pending: bool,
    lost: bool,
    /// SysTick counts of this period spent waiting for the adapter's bytes.
    idle_counts: u32,
    /// SysTick's value when the current wait began, or [`NOT_WAITING`].
    idle_since: u32,
}

/// [`SlcanCan::idle_since`] outside a wait (SysTick's value never exceeds its reload).
const NOT_WAITING: u32 = u32::MAX;

/// SysTick's current value: it counts down from [`PERIOD_COUNTS`] each period.
fn systick_now() -> u32 {
    // SAFETY: SysTick's current-value register; reading it has no effect.
    unsafe { read_volatile(0xE000_E018 as *const u32) }
}

/// SysTick counts from `earlier` to `now`, across one reload at most.
#[inline(never)]
fn counts_since(earlier: u32, now: u32) -> u32 {
    if earlier >= now {
        earlier - now
    } else {
        earlier + PERIOD_COUNTS - now
    }
}

impl SlcanCan {
    /// Times the waits for the adapter's bytes: a wait begins at the first empty poll and ends
    /// with the next byte.
    #[inline(never)]
    fn note_wait(&mut self, waiting: bool) {
        if waiting {
            if self.idle_since == NOT_WAITING {
                self.idle_since = systick_now();
            }
        } else if self.idle_since != NOT_WAITING {
            self.idle_counts += counts_since(self.idle_since, systick_now());
            self.idle_since = NOT_WAITING;
        }
    }
}

/// The adapter refused a frame (only a frame longer than 8 bytes, which `CanFrame` never is).
#[derive(Debug)]
struct LineError;

impl embedded_can::Error for LineError {
    fn kind(&self) -> embedded_can::ErrorKind {
        embedded_can::ErrorKind::Other
    }
}

impl embedded_can::nb::Can for SlcanCan {
    type Frame = CanFrame;
    type Error = LineError;

    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, LineError> {
        let line = slcan::encode_frame(frame, None).map_err(|_| nb::Error::Other(LineError))?;
        self.uart.write(line.as_bytes());
        Ok(None)
    }

    fn receive(&mut self) -> nb::Result<CanFrame, LineError> {
        while self.polled {
            let byte = self.uart.try_read();
            self.note_wait(byte.is_none());
            let Some(byte) = byte else {
                if period_began() {
                    self.period_pending = true;
                    self.waited += 1;
                    if self.waited >= CAN_LINK_TIMEOUT_PERIODS {
                        self.lost = true;
                        self.polled = false;
                    }
                }
                continue;
            };
            match self.decoder.feed_from_adapter(byte) {
                Ok(Some(AdapterMessage::Frame { frame, .. })) => return Ok(frame),
                Ok(Some(AdapterMessage::Reply(Reply::StatusFlags(_)))) => self.polled = false,
                // The adapter's CR and `z` answers, and lines it garbled (counted).
                _ => {}
            }
        }
        Err(nb::Error::WouldBlock)
    }
}

/// SysTick's reload for one 10 ms period of the machine's 25 MHz clock.
const PERIOD_COUNTS: u32 = 250_000;

/// The board: the CAN adapter and SysTick's period.
struct SlcanBoard {
    can: SlcanCan,
    /// SysTick's value when the current period's work began.
    period_start: u32,
}

/// The most SysTick counts of work in one control period since boot, the waits for the
/// adapter's bytes left out: on QEMU's `-icount shift=0` clock a count is 40 instructions.
/// Nothing in the firmware reads it; the host reads it from outside, through QEMU's monitor at
/// this symbol's address (the link has no field for it: flash has no room for one).
#[no_mangle]
static BUSIEST_PERIOD_COUNTS: AtomicU32 = AtomicU32::new(0);

impl SlcanBoard {
    fn new(uart: Uart) -> SlcanBoard {
        let mut can = SlcanCan {
            uart,
            decoder: Decoder::new(),
            polled: false,
            waited: 0,
            period_pending: false,
            lost: false,
            idle_counts: 0,
            idle_since: NOT_WAITING,
        };
        // Close, 1 Mbit/s, open: the adapter's answers are read (and ignored) with the frames.
        can.uart.write(b"C\rS8\rO\r");
        // SAFETY: SysTick's reload, current value and control registers (enable, interrupt,
        // processor clock); no memory effects.
        unsafe {
            write_volatile(0xE000_E014 as *mut u32, PERIOD_COUNTS - 1);
            write_volatile(0xE000_E018 as *mut u32, 0);
            write_volatile(0xE000_E010 as *mut u32, 0b111);
        }
        SlcanBoard {
            can,
            period_start: 0,
        }
    }

    /// Whether a period began (latched until [`Board::wait_for_tick`] starts it).
    fn period_due(&mut self) -> bool {
        self.can.period_pending |= period_began();
        self.can.period_pending
    }
}

impl Board for SlcanBoard {
    type Frame = CanFrame;
    type Can = SlcanCan;

    fn can(&mut self) -> &mut SlcanCan {
        &mut self.can
    }

    fn wait_for_tick(&mut self) {
        while !core::mem::take(&mut self.can.period_pending) {
            self.can.period_pending = period_began();
            if !self.can.period_pending {
                sleep_until_period();
            }
        }
        self.period_start = systick_now();
        self.can.idle_counts = 0;
        self.can.idle_since = NOT_WAITING;
        self.can.uart.write(b"F\r");
        self.can.polled = !self.can.lost;
        self.can.waited = 0;
    }

    fn link_lost(&self) -> bool {
        self.can.lost
    }

    fn tick_done(&mut self) {
        let busy =
            counts_since(self.period_start, systick_now()).saturating_sub(self.can.idle_counts);
        // Only the main loop writes it: a load and a store, not an atomic read-modify-write.
        if busy > BUSIEST_PERIOD_COUNTS.load(Ordering::Relaxed) {
            BUSIEST_PERIOD_COUNTS.store(busy, Ordering::Relaxed);
        }
    }
}

/// The observation link: COBS frames in, decoded into the receiver's buffer as they come.
struct Link {
    uart: Uart,
    cobs: cobs::DecoderState,
    len: usize,
    too_long: bool,
}

/// What waiting on the observation link brought.
enum Received {
    /// A decoded frame of this many bytes is in the buffer.
    Frame(usize),
    /// A frame that is no frame (bad COBS, too long).
    Bad,
    /// A control period went by (the robot was held in it).
    Period,
}

impl Link {
    /// Reads bytes into `buf` until a frame ends or, once the robot is under control, a
    /// control period begins (it runs one, holding the robot).
    fn receive(
        &mut self,
        buf: &mut [u8],
        board: &mut SlcanBoard,
        mut control: Option<&mut Control<CanFrame>>,
    ) -> Received {
        loop {
            // Every turn, not only when the link is quiet: a flood of bytes must not starve
            // the control period.
            if let Some(control) = control.as_deref_mut() {
                if board.period_due() {
                    // A frame that cannot be queued stops the robot in the next period.
                    if control.hold(board).is_err() {
                        control.stop(StopReason::Control);
                    }
                    return Received::Period;
                }
            }
            let Some(byte) = self.uart.try_read() else {
                continue;
            };
            match self.cobs.feed(byte) {
                Ok(cobs::DecodeResult::NoData) => {}
                Ok(cobs::DecodeResult::DataContinue(value)) => {
                    match buf.get_mut(self.len) {
                        Some(slot) => *slot = value,
                        None => self.too_long = true,
                    }
                    self.len += 1;
                }
                Ok(cobs::DecodeResult::DataComplete) => {
                    let len = core::mem::take(&mut self.len);
                    if !core::mem::take(&mut self.too_long) {
                        return Received::Frame(len);
                    }
                    return Received::Bad;
                }
                Err(_) => {
                    self.len = 0;
                    self.too_long = false;
                    return Received::Bad;
                }
            }
        }
    }

    /// Sends one message (a small one: all of the controller's are).
    fn send(&mut self, message: FromController) {
        let mut scratch = [0u8; 64];
        let mut frame = [0u8; 72];
        if let Ok(len) = wire::seal(message, &mut scratch, &mut frame) {
            self.uart.write(frame.get(..len).unwrap_or(&[]));
        }
    }
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
                        let started = empty.insert(Control::new(WHEELLEG, observation.legs()));
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
