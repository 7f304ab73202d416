//! mps2-an386's parts the production image drives: SysTick's 100 Hz period and its priority,
//! the CMSDK UARTs, the receive interrupt of the CAN adapter's UART, a free-running timer, and
//! the CAN bus behind an SLCAN adapter on UART 2 as the control loop's [`Board`]. A real
//! board's HAL puts its FDCAN driver and timer here (docs/controller.md).

use core::arch::asm;
use core::cell::RefCell;
use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::interrupt::{self, Mutex};
use heapless::spsc::Producer;
#[cfg(not(feature = "emulated-clock"))]
use heapless::spsc::{Consumer, Queue};
use wheelleg_controller::control::{Board, CAN_LINK_TIMEOUT_PERIODS};
#[cfg(not(feature = "emulated-clock"))]
use wheelleg_controller::link::Buffer;
use wheelleg_runtime::can::slcan::{self, AdapterMessage, Decoder, Reply};
use wheelleg_runtime::can::CanFrame;

/// Bytes from the CAN adapter not yet read by the control period: a period's feedback (16
/// encoder estimates and the heartbeats, some 500 to 900 bytes of SLCAN lines) several times
/// over.
#[cfg(not(feature = "emulated-clock"))]
const ADAPTER_BYTES: usize = 4_096;

#[cfg(not(feature = "emulated-clock"))]
static ADAPTER_QUEUE: Buffer<Queue<u8, ADAPTER_BYTES>> = Buffer::new(Queue::new());
/// The receive interrupt's end of the adapter's byte queue, put in place before the interrupt
/// is enabled.
static ADAPTER_RX: Mutex<RefCell<Option<Producer<'static, u8>>>> = Mutex::new(RefCell::new(None));

/// Interrupt priorities (the top bits of the priority byte: lower is more urgent). The CAN
/// adapter's bytes are taken at once, above the control period, which must be able to wait
/// for them; the control period runs above the decision (thread mode).
const ADAPTER_RX_PRIORITY: u8 = 0x00;
/// The control period's (SysTick's) priority.
const PERIOD_PRIORITY: u8 = 0x80;
/// mps2-an386's interrupt number of UART 2's receiver.
pub(crate) const UART2_RX_IRQ: usize = 4;

/// Sleeps until an interrupt unless `ready` holds already. Interrupts are masked from the test
/// to the `wfi`, so that one taken between them cannot leave the core asleep; `wfi` still
/// wakes for a masked interrupt.
///
/// The emulated clock's image never sleeps: QEMU's instruction clock, skipping idle time,
/// skips every other SysTick interrupt when `wfi` waits for it (measured: 20 ms between
/// periods instead of 10), so that image spins, as a core busy with a decision does.
pub(crate) fn sleep_unless(ready: impl FnOnce() -> bool) {
    if cfg!(feature = "emulated-clock") {
        let _ = ready();
        return;
    }
    // SAFETY: masking and unmasking interrupts, and `wfi`, touch no memory.
    unsafe { asm!("cpsid i", options(nomem, nostack)) };
    if !ready() {
        unsafe { asm!("wfi", options(nomem, nostack)) };
    }
    unsafe { asm!("cpsie i", options(nomem, nostack)) };
}

/// A CMSDK UART of mps2-an386.
pub(crate) struct Uart(usize);

impl Uart {
    pub(crate) const UART1: usize = 0x4000_5000;
    pub(crate) const UART2: usize = 0x4000_6000;

    /// Enables the transmitter and the receiver (polled).
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

/// UART 2's receive interrupt: the adapter's bytes into the queue. The interrupt's flag is
/// cleared before the bytes are read, so that a byte arriving after the last read raises it
/// again rather than wait unseen (QEMU holds the next byte until this one is read).
pub(crate) unsafe extern "C" fn uart2_rx() {
    // SAFETY: the CMSDK UART's interrupt clear register.
    unsafe { write_volatile((Uart::UART2 + 0x0C) as *mut u32, 0b10) };
    let mut uart = Uart(Uart::UART2);
    interrupt::free(|cs| {
        if let Some(producer) = ADAPTER_RX.borrow(cs).borrow_mut().as_mut() {
            while let Some(byte) = uart.try_read() {
                // A full queue drops the byte: the decoder counts the line garbled.
                let _ = producer.enqueue(byte);
            }
        }
    });
}

/// SysTick's current value: it counts down from [`PERIOD_COUNTS`] each period.
fn systick_now() -> u32 {
    // SAFETY: SysTick's current-value register; reading it has no effect.
    unsafe { read_volatile(0xE000_E018 as *const u32) }
}

/// Whether SysTick reached zero since the last asking (its control register's COUNTFLAG,
/// which reading clears): a period boundary passed.
fn systick_wrapped() -> bool {
    // SAFETY: SysTick's control register; reading it clears COUNTFLAG only.
    unsafe { read_volatile(0xE000_E010 as *const u32) & (1 << 16) != 0 }
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

/// The CAN bus behind an SLCAN adapter on a UART: frames out as `t` lines, the adapter's frame
/// lines in from the receive interrupt's queue.
///
/// Each period polls the adapter's status (`F`) unless the last poll is still unanswered;
/// [`CAN_LINK_TIMEOUT_PERIODS`] periods without an answer lose the link. In lockstep (the
/// default image) a period reads up to the poll's answer, waiting for it, so that the HIL's
/// motors, which advance one period per poll, and the firmware keep step however fast QEMU
/// runs. With the `emulated-clock` feature a period never waits: it reads what has come, as
/// from a board's own CAN peripheral, and stamps its frames with the time.
pub(crate) struct SlcanCan {
    uart: Uart,
    /// In lockstep: the adapter's bytes, from the receive interrupt.
    #[cfg(not(feature = "emulated-clock"))]
    bytes: Consumer<'static, u8>,
    /// With the emulated clock: the adapter's bytes, from the HIL's FIFO.
    #[cfg(feature = "emulated-clock")]
    adapter: Emulated,
    decoder: Decoder,
    /// The last status poll is not answered yet.
    polled: bool,
    /// Periods the poll has waited.
    waited: u32,
    lost: bool,
    /// SysTick counts of this period spent waiting for the adapter's bytes.
    idle_counts: u32,
    /// SysTick's value when the current wait began, or [`NOT_WAITING`].
    idle_since: u32,
}

/// [`SlcanCan::idle_since`] outside a wait (SysTick's value never exceeds its reload).
const NOT_WAITING: u32 = u32::MAX;

impl SlcanCan {
    /// Times the waits for the adapter's bytes: a wait begins at the first empty poll and ends
    /// with the next byte.
    #[cfg(not(feature = "emulated-clock"))]
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

    /// The next byte from the adapter: in lockstep, waiting for it while the poll is
    /// unanswered, until [`CAN_LINK_TIMEOUT_PERIODS`] period boundaries pass.
    #[cfg(not(feature = "emulated-clock"))]
    fn next_byte(&mut self) -> Option<u8> {
        loop {
            let byte = self.bytes.dequeue();
            if byte.is_some() || cfg!(feature = "emulated-clock") || !self.polled {
                self.note_wait(false);
                return byte;
            }
            self.note_wait(true);
            if systick_wrapped() {
                self.waited += 1;
                if self.waited >= CAN_LINK_TIMEOUT_PERIODS {
                    self.lost = true;
                    self.polled = false;
                }
            }
        }
    }
}

/// The emulated clock's side of the adapter: the HIL writes the adapter's bytes into a FIFO
/// the firmware reads by semihosting, and after each period's stamp a zero byte (which no
/// SLCAN line contains): everything on the bus up to the stamp has come. A read waits in the
/// host, at no cost to the emulated clock, as a board's CAN peripheral holds its frames
/// ready; so the period reads its feedback at once, deterministically, however fast the
/// host runs, and QEMU's one-byte UART does not limit the bus's rate.
#[cfg(feature = "emulated-clock")]
pub(crate) struct Emulated {
    fifo: wheelleg_controller::semihosting::File,
    buf: [u8; 256],
    len: usize,
    at: usize,
    /// This period's bytes have all been read (its zero byte came).
    synced: bool,
}

#[cfg(feature = "emulated-clock")]
impl Emulated {
    /// The FIFO the HIL made in QEMU's working folder.
    const FIFO: &'static [u8] = b"adapter.fifo\0";

    fn open() -> Option<Emulated> {
        use wheelleg_controller::semihosting::{File, Mode};
        Some(Emulated {
            fifo: File::open(Self::FIFO, Mode::Read)?,
            buf: [0; 256],
            len: 0,
            at: 0,
            synced: true,
        })
    }

    /// The period's next byte, `None` once its zero byte came.
    fn next(&mut self) -> Option<u8> {
        if self.synced {
            return None;
        }
        if self.at == self.len {
            self.len = self.fifo.read_some(&mut self.buf);
            self.at = 0;
            if self.len == 0 {
                // The HIL closed the FIFO: nothing more comes.
                self.synced = true;
                return None;
            }
        }
        let byte = self.buf.get(self.at).copied();
        self.at += 1;
        match byte {
            Some(0) | None => {
                self.synced = true;
                None
            }
            byte => byte,
        }
    }
}

#[cfg(feature = "emulated-clock")]
impl SlcanCan {
    /// The next byte from the adapter, up to the period's zero byte.
    fn next_byte(&mut self) -> Option<u8> {
        self.adapter.next()
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
        // In lockstep the frames after the poll's answer are the next period's.
        while self.polled || cfg!(feature = "emulated-clock") {
            let byte = self.next_byte().ok_or(nb::Error::WouldBlock)?;
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

/// CMSDK APB timer 0: free-running on the machine's 25 MHz clock, the emulated clock's
/// stamps.
const TIMER0: usize = 0x4000_0000;

/// The board: the CAN adapter and SysTick's period.
pub(crate) struct SlcanBoard {
    can: SlcanCan,
    /// SysTick's value when the current period's work began.
    period_start: u32,
}

/// The most SysTick counts of work in one control period since boot, the waits for the
/// adapter's bytes left out: on QEMU's `-icount shift=0` clock a count is 40 instructions.
/// Nothing in the firmware reads it; the host reads it from outside, through QEMU's monitor at
/// this symbol's address.
#[no_mangle]
static BUSIEST_PERIOD_COUNTS: AtomicU32 = AtomicU32::new(0);

impl SlcanBoard {
    /// Opens the adapter (close, 1 Mbit/s, open: its answers are read, and ignored, with the
    /// frames), takes its bytes by interrupt, and starts SysTick's period at its priority and
    /// the free-running timer. `None` if called twice.
    pub(crate) fn start(mut uart: Uart) -> Option<SlcanBoard> {
        #[cfg(not(feature = "emulated-clock"))]
        let bytes = {
            let (producer, consumer) = ADAPTER_QUEUE.take()?.split();
            interrupt::free(|cs| ADAPTER_RX.borrow(cs).replace(Some(producer)));
            consumer
        };
        #[cfg(feature = "emulated-clock")]
        let adapter = Emulated::open()?;
        // SAFETY: UART 2's control register (transmitter, receiver, receive interrupt), the
        // NVIC's priority and enable registers of its interrupt, SysTick's priority (SHPR3),
        // reload, current value and control registers (enable, interrupt, processor clock),
        // and timer 0's reload and control: device registers, no memory effects.
        unsafe {
            // The emulated clock's adapter bytes come by semihosting, not by the UART.
            let receive_interrupt = if cfg!(feature = "emulated-clock") {
                0
            } else {
                0b1000
            };
            write_volatile((uart.0 + 0x08) as *mut u32, 0b11 | receive_interrupt);
            write_volatile((0xE000_E400 + UART2_RX_IRQ) as *mut u8, ADAPTER_RX_PRIORITY);
            write_volatile(0xE000_E100 as *mut u32, 1 << UART2_RX_IRQ);
            write_volatile(0xE000_ED23 as *mut u8, PERIOD_PRIORITY);
            write_volatile((TIMER0 + 0x08) as *mut u32, u32::MAX);
            write_volatile(TIMER0 as *mut u32, 1);
        }
        uart.write(b"C\rS8\rO\r");
        // SAFETY: as above.
        unsafe {
            write_volatile(0xE000_E014 as *mut u32, PERIOD_COUNTS - 1);
            write_volatile(0xE000_E018 as *mut u32, 0);
            write_volatile(0xE000_E010 as *mut u32, 0b111);
        }
        Some(SlcanBoard {
            can: SlcanCan {
                uart,
                #[cfg(not(feature = "emulated-clock"))]
                bytes,
                #[cfg(feature = "emulated-clock")]
                adapter,
                decoder: Decoder::new(),
                polled: false,
                waited: 0,
                lost: false,
                idle_counts: 0,
                idle_since: NOT_WAITING,
            },
            period_start: 0,
        })
    }
}

/// Timer 0's counts since it started (it counts down from its reload, `u32::MAX`).
fn timer0_counts() -> u32 {
    // SAFETY: timer 0's value register; reading it has no effect.
    u32::MAX - unsafe { read_volatile((TIMER0 + 0x04) as *const u32) }
}

/// A stamp line of the emulated clock: `kind`, timer 0's counts in 8 hex digits, CR. `@` starts
/// a period (the HIL answers with the bus's bytes up to that time, then a zero byte), `!`
/// precedes its setpoints.
fn stamp_line(kind: u8) -> [u8; 10] {
    let mut line = [kind, 0, 0, 0, 0, 0, 0, 0, 0, b'\r'];
    if let Some(digits) = line.get_mut(1..9) {
        digits.copy_from_slice(&hex8(timer0_counts()));
    }
    line
}

/// Hex digits of `value`, most significant first.
fn hex8(value: u32) -> [u8; 8] {
    let mut out = [0u8; 8];
    for (i, slot) in out.iter_mut().enumerate() {
        let nibble = (value >> (28 - 4 * i)) & 0xF;
        *slot = b"0123456789ABCDEF"
            .get(nibble as usize)
            .copied()
            .unwrap_or(b'0');
    }
    out
}

impl Board for SlcanBoard {
    type Frame = CanFrame;
    type Can = SlcanCan;

    fn can(&mut self) -> &mut SlcanCan {
        &mut self.can
    }

    /// The period's interrupt is its start: poll the adapter unless the last poll is still
    /// unanswered.
    fn wait_for_tick(&mut self) {
        // This period's own boundary is not a wait's.
        let _ = systick_wrapped();
        self.period_start = systick_now();
        self.can.idle_counts = 0;
        self.can.idle_since = NOT_WAITING;
        if self.can.lost {
            // Still polled, unanswered, so that the adapter's side counts the periods on.
            self.can.uart.write(b"F\r");
            #[cfg(feature = "emulated-clock")]
            {
                self.can.uart.write(&stamp_line(b'@'));
                self.can.adapter.synced = false;
            }
            return;
        }
        if self.can.polled {
            self.can.waited += 1;
            if self.can.waited >= CAN_LINK_TIMEOUT_PERIODS {
                self.can.lost = true;
                self.can.polled = false;
            }
        } else {
            self.can.uart.write(b"F\r");
            self.can.polled = true;
            self.can.waited = 0;
        }
        #[cfg(feature = "emulated-clock")]
        {
            self.can.uart.write(&stamp_line(b'@'));
            self.can.adapter.synced = false;
        }
    }

    fn link_lost(&self) -> bool {
        self.can.lost
    }

    /// With the emulated clock, the period's setpoints follow a stamp line (`!`): the HIL's
    /// motors advance to its time before they take them, and it is checked against the
    /// period's due time.
    fn sending(&mut self) {
        if cfg!(feature = "emulated-clock") {
            self.can.uart.write(&stamp_line(b'!'));
        }
    }

    fn tick_done(&mut self) {
        let busy =
            counts_since(self.period_start, systick_now()).saturating_sub(self.can.idle_counts);
        // Only the period writes it: a load and a store, not an atomic read-modify-write.
        if busy > BUSIEST_PERIOD_COUNTS.load(Ordering::Relaxed) {
            BUSIEST_PERIOD_COUNTS.store(busy, Ordering::Relaxed);
        }
    }
}
