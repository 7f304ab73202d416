//! QEMU's mps2-an386 (Cortex-M4F) as the controller's board: CMSDK UART 0 as the console,
//! SysTick as the clock that counts instructions, and a CAN peripheral that replays a recorded
//! bus (the axes' feedback of each control period in, the controller's frames out to a file).

use core::ptr::{read_volatile, write_volatile};

use embedded_can::{Frame, Id, StandardId};
use wheelleg_controller::control::Board;
use wheelleg_runtime::can::CanFrame;

use wheelleg_controller::semihosting::File;

const UART0: usize = 0x4000_4000;
const UART_DATA: usize = UART0;
const UART_STATE: usize = UART0 + 0x04;
const UART_CTRL: usize = UART0 + 0x08;
const UART_BAUDDIV: usize = UART0 + 0x10;
const SYST_CSR: usize = 0xE000_E010;
const SYST_RVR: usize = 0xE000_E014;
const SYST_CVR: usize = 0xE000_E018;
/// SysTick's 24-bit counter.
const SYST_MASK: u32 = 0x00FF_FFFF;

/// The console: CMSDK UART 0 (QEMU connects it to standard output).
pub struct Uart;

impl Uart {
    /// Enables the transmitter.
    pub fn new() -> Uart {
        // SAFETY: the CMSDK UART's registers on mps2-an386; writing them has no effect on
        // memory.
        unsafe {
            write_volatile(UART_BAUDDIV as *mut u32, 16);
            write_volatile(UART_CTRL as *mut u32, 1);
        }
        Uart
    }

    /// Writes `bytes`, waiting while the transmit buffer is full.
    pub fn write(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            // SAFETY: as in `new`: device registers.
            unsafe {
                while read_volatile(UART_STATE as *const u32) & 1 != 0 {}
                write_volatile(UART_DATA as *mut u32, u32::from(byte));
            }
        }
    }

    /// Writes `value` in decimal (no `core::fmt`: it would cost kilobytes of flash).
    pub fn number(&mut self, value: u64) {
        let mut digits = [0u8; 20];
        let mut at = digits.len();
        let mut rest = value;
        loop {
            at -= 1;
            if let Some(slot) = digits.get_mut(at) {
                *slot = b'0' + (rest % 10) as u8;
            }
            rest /= 10;
            if rest == 0 || at == 0 {
                break;
            }
        }
        self.write(digits.get(at..).unwrap_or(&[]));
    }

    /// `key=value ` on the console.
    pub fn field(&mut self, key: &str, value: u64) {
        self.write(key.as_bytes());
        self.write(b"=");
        self.number(value);
        self.write(b" ");
    }
}

/// SysTick on the processor clock. Under `-icount shift=0` QEMU's virtual clock advances one
/// nanosecond per instruction, and the machine's 25 MHz clock ticks SysTick every 40 of them.
pub struct Clock;

impl Clock {
    /// Instructions per SysTick count at 25 MHz and 1 ns per instruction.
    pub const INSTRUCTIONS_PER_TICK: u64 = 40;

    /// Starts SysTick counting down from its largest value.
    pub fn start() -> Clock {
        // SAFETY: the System Control Space's SysTick registers; no memory effects.
        unsafe {
            write_volatile(SYST_RVR as *mut u32, SYST_MASK);
            write_volatile(SYST_CVR as *mut u32, 0);
            write_volatile(SYST_CSR as *mut u32, 0b101);
        }
        Clock
    }

    /// The counter (counts down, wraps every 2^24 counts: 671 M instructions).
    pub fn now(&self) -> u32 {
        // SAFETY: as in `start`.
        unsafe { read_volatile(SYST_CVR as *const u32) }
    }

    /// Instructions from `start` (an earlier `now`) to now, to the nearest 40.
    pub fn instructions_since(&self, start: u32) -> u64 {
        let ticks = start.wrapping_sub(self.now()) & SYST_MASK;
        u64::from(ticks) * Self::INSTRUCTIONS_PER_TICK
    }
}

/// Tags of the recorded episode's entries.
pub mod tag {
    /// The end of the recording.
    pub const END: u8 = 0;
    /// The start-up sequence begins.
    pub const STARTUP: u8 = 1;
    /// A decision: an observation record follows.
    pub const DECISION: u8 = 2;
    /// One control period: the frames received in it follow.
    pub const TICK: u8 = 3;
}

/// Bytes of one frame in the recording and in the output: id (u16), length, 8 data bytes.
pub const FRAME_BYTES: usize = 11;

/// Set in a recorded frame's id for a remote (RTR) frame: standard ids use 11 bits, and
/// `examples/mcu_vectors.rs` records remote frames the same way.
const REMOTE_FLAG: u16 = 0x8000;

/// A CAN peripheral replaying a recording: `receive` hands out the frames the recorded
/// period received (read from the recording as they are asked for, so no buffer holds them),
/// `transmit` writes each frame with its period's index to a file.
pub struct ReplayCan {
    input: File,
    output: File,
    /// Frames of the current period not yet received.
    pending: usize,
    /// Periods replayed so far.
    pub ticks: u32,
    /// Frames sent.
    pub sent: u32,
    /// Set when the recording had no period where the controller ran one, or was unreadable.
    pub desync: bool,
}

/// Never happens for the replay (the output file takes every frame).
#[derive(Debug)]
pub struct ReplayError;

impl embedded_can::Error for ReplayError {
    fn kind(&self) -> embedded_can::ErrorKind {
        embedded_can::ErrorKind::Other
    }
}

impl ReplayCan {
    /// Replays `input` (positioned after its header), writes to `output`.
    pub fn new(input: File, output: File) -> ReplayCan {
        ReplayCan {
            input,
            output,
            pending: 0,
            ticks: 0,
            sent: 0,
            desync: false,
        }
    }

    /// The next entry's tag.
    pub fn next_tag(&mut self) -> Option<u8> {
        let mut tag = [0u8];
        self.input.read_exact(&mut tag).then_some(tag[0])
    }

    /// Reads `buf` from the recording.
    pub fn read(&mut self, buf: &mut [u8]) -> bool {
        self.input.read_exact(buf)
    }

    /// Starts the next period: its frames are received next.
    fn load_tick(&mut self) {
        // Frames of the last period the controller did not read are skipped.
        while self.pending > 0 {
            if self.next_frame().is_none() {
                return;
            }
        }
        let mut count = [0u8];
        if self.next_tag() != Some(tag::TICK) || !self.input.read_exact(&mut count) {
            self.desync = true;
            return;
        }
        self.pending = usize::from(count[0]);
        self.ticks += 1;
    }

    /// The next recorded frame of this period.
    fn next_frame(&mut self) -> Option<CanFrame> {
        self.pending = self.pending.checked_sub(1)?;
        let mut bytes = [0u8; FRAME_BYTES];
        if !self.input.read_exact(&mut bytes) {
            self.desync = true;
            self.pending = 0;
            return None;
        }
        let [lo, hi, len, data @ ..] = bytes;
        let raw = u16::from_le_bytes([lo, hi]);
        let frame = StandardId::new(raw & !REMOTE_FLAG).and_then(|id| {
            if raw & REMOTE_FLAG != 0 {
                CanFrame::new_remote(id, usize::from(len))
            } else {
                CanFrame::new(id, data.get(..usize::from(len)).unwrap_or(&[]))
            }
        });
        if frame.is_none() {
            self.desync = true;
        }
        frame
    }
}

impl embedded_can::nb::Can for ReplayCan {
    type Frame = CanFrame;
    type Error = ReplayError;

    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, ReplayError> {
        let mut bytes = [0u8; 4 + FRAME_BYTES];
        let (tick, rest) = bytes.split_at_mut(4);
        tick.copy_from_slice(&self.ticks.to_le_bytes());
        let id = match frame.id() {
            Id::Standard(id) if frame.is_remote_frame() => id.as_raw() | REMOTE_FLAG,
            Id::Standard(id) => id.as_raw(),
            Id::Extended(_) => u16::MAX,
        };
        let [lo, hi] = id.to_le_bytes();
        let [id_lo, id_hi, len, data @ ..] = rest else {
            return Err(nb::Error::Other(ReplayError));
        };
        (*id_lo, *id_hi, *len) = (lo, hi, frame.dlc() as u8);
        for (slot, &byte) in data.iter_mut().zip(frame.data()) {
            *slot = byte;
        }
        self.sent += 1;
        if self.output.write_all(&bytes) {
            Ok(None)
        } else {
            Err(nb::Error::Other(ReplayError))
        }
    }

    fn receive(&mut self) -> nb::Result<CanFrame, ReplayError> {
        self.next_frame().ok_or(nb::Error::WouldBlock)
    }
}

/// The board of the episode replay: the replayed CAN and no waiting (QEMU's periods are the
/// recording's).
pub struct ReplayBoard {
    /// The CAN peripheral.
    pub can: ReplayCan,
}

impl Board for ReplayBoard {
    type Frame = CanFrame;
    type Can = ReplayCan;

    fn can(&mut self) -> &mut ReplayCan {
        &mut self.can
    }

    fn wait_for_tick(&mut self) {
        self.can.load_tick();
    }
}
