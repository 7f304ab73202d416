//! mps2-an386's parts the production image drives: SysTick's 100 Hz period, the CMSDK UARTs
//! (polled), and the CAN bus behind an SLCAN adapter on UART 2, as the control loop's
//! [`Board`]. A real board's HAL puts its FDCAN driver and timer here (docs/controller.md).

use core::arch::asm;
use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use cortex_m_rt::exception;
use wheelleg_controller::control::{Board, CAN_LINK_TIMEOUT_PERIODS};
use wheelleg_runtime::can::slcan::{self, AdapterMessage, Decoder, Reply};
use wheelleg_runtime::can::CanFrame;

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

/// A CMSDK UART of mps2-an386, polled.
pub(crate) struct Uart(usize);

impl Uart {
    pub(crate) const UART1: usize = 0x4000_5000;
    pub(crate) const UART2: usize = 0x4000_6000;

    /// Enables the transmitter and the receiver.
    pub(crate) fn new(base: usize) -> Uart {
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
    pub(crate) fn write(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            while self.state() & 1 != 0 {}
            // SAFETY: as in `new`.
            unsafe { write_volatile(self.0 as *mut u32, u32::from(byte)) };
        }
    }

    /// A received byte, if one is waiting.
    pub(crate) fn try_read(&mut self) -> Option<u8> {
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
pub(crate) struct SlcanCan {
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
pub(crate) struct LineError;

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
pub(crate) struct SlcanBoard {
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
    pub(crate) fn new(uart: Uart) -> SlcanBoard {
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
    pub(crate) fn period_due(&mut self) -> bool {
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
