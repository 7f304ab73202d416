//! The production image on QEMU's mps2-an386 (Cortex-M4F): what flash is measured on. Boots,
//! checks the weights file, then decides and drives, with none of the check harness
//! (semihosting, replay, counts, the scalar kernel's comparison: `src/check/main.rs`).
//!
//! Its links stand in for a real board's: observations arrive on CMSDK UART 1 (the record of
//! `link::read_observation`, then the fine window's `i16` little-endian heights), each
//! decision's record leaves on it; the ODrive bus is a CAN bridge on UART 2 (each frame as
//! id, length and 8 data bytes), and SysTick paces the 100 Hz period. A board's HAL puts its
//! FDCAN driver and timer in their place (docs/controller.md).
#![no_std]
#![no_main]

use core::arch::asm;
use core::mem::MaybeUninit;
use core::panic::PanicInfo;
use core::ptr::{read_volatile, write_volatile};

use cortex_m_rt::entry;
use embedded_can::{Frame, Id, StandardId};
use wheelleg_controller::control::{Board, Control};
use wheelleg_controller::link::{read_observation, Buffer};
use wheelleg_controller::stack::{
    ControllerDecider, Observation, Stack, ROW_ELEMENTS, WINDOW_BYTES, WORK_BYTES,
};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::robot::WHEELLEG;

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

/// Interrupts of the vector table: the 32 of QEMU's mps2-an386 (CMSDK peripherals), none
/// used (the controller polls its peripherals), each parked in a loop.
#[link_section = ".vector_table.interrupts"]
#[no_mangle]
static __INTERRUPTS: [unsafe extern "C" fn(); 32] = [unused_interrupt; 32];

/// An interrupt nothing enabled: stop here.
unsafe extern "C" fn unused_interrupt() {
    halt()
}

/// Stops the core (an unused interrupt, a panic, a failed boot check, a lost link).
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

    /// Fills `buf`, waiting for each byte.
    fn read_exact(&mut self, buf: &mut [u8]) -> bool {
        for slot in buf.iter_mut() {
            *slot = loop {
                if let Some(byte) = self.try_read() {
                    break byte;
                }
            };
        }
        true
    }
}

/// Bytes of a bridged CAN frame: id (u16), length, 8 data bytes.
const FRAME_BYTES: usize = 11;

/// The CAN bridge: frames over a UART, a received frame handed out once all its bytes came.
struct BridgeCan {
    uart: Uart,
    partial: [u8; FRAME_BYTES],
    have: usize,
}

/// The bridge's only error: a received frame that no CAN frame can be.
#[derive(Debug)]
struct BridgeError;

impl embedded_can::Error for BridgeError {
    fn kind(&self) -> embedded_can::ErrorKind {
        embedded_can::ErrorKind::Other
    }
}

impl embedded_can::nb::Can for BridgeCan {
    type Frame = CanFrame;
    type Error = BridgeError;

    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, BridgeError> {
        let id = match frame.id() {
            Id::Standard(id) => id.as_raw(),
            Id::Extended(_) => u16::MAX,
        };
        let mut bytes = [0u8; FRAME_BYTES];
        let [lo, hi] = id.to_le_bytes();
        let [id_lo, id_hi, len, data @ ..] = &mut bytes;
        (*id_lo, *id_hi, *len) = (lo, hi, frame.dlc() as u8);
        for (slot, &byte) in data.iter_mut().zip(frame.data()) {
            *slot = byte;
        }
        self.uart.write(&bytes);
        Ok(None)
    }

    fn receive(&mut self) -> nb::Result<CanFrame, BridgeError> {
        while self.have < FRAME_BYTES {
            let byte = self.uart.try_read().ok_or(nb::Error::WouldBlock)?;
            if let Some(slot) = self.partial.get_mut(self.have) {
                *slot = byte;
            }
            self.have += 1;
        }
        self.have = 0;
        let [lo, hi, len, data @ ..] = self.partial;
        StandardId::new(u16::from_le_bytes([lo, hi]))
            .and_then(|id| CanFrame::new(id, data.get(..usize::from(len))?))
            .ok_or(nb::Error::Other(BridgeError))
    }
}

/// SysTick's reload for one 10 ms period of the machine's 25 MHz clock.
const PERIOD_COUNTS: u32 = 250_000;

/// The board: the CAN bridge and SysTick's period.
struct BridgeBoard {
    can: BridgeCan,
}

impl BridgeBoard {
    fn new(can: BridgeCan) -> BridgeBoard {
        // SAFETY: SysTick's reload, current value and control registers; no memory effects.
        unsafe {
            write_volatile(0xE000_E014 as *mut u32, PERIOD_COUNTS - 1);
            write_volatile(0xE000_E018 as *mut u32, 0);
            write_volatile(0xE000_E010 as *mut u32, 0b101);
        }
        BridgeBoard { can }
    }
}

impl Board for BridgeBoard {
    type Frame = CanFrame;
    type Can = BridgeCan;

    fn can(&mut self) -> &mut BridgeCan {
        &mut self.can
    }

    fn wait_for_tick(&mut self) {
        // SAFETY: SysTick's control register; reading it clears COUNTFLAG (bit 16), set when
        // the counter wrapped: the period began.
        while unsafe { read_volatile(0xE000_E010 as *const u32) } & (1 << 16) == 0 {}
    }
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
    let window_bytes = (2 * stack.window().cells()).min(WINDOW_BYTES);
    let mut link = Uart::new(Uart::UART1);
    let mut board = BridgeBoard::new(BridgeCan {
        uart: Uart::new(Uart::UART2),
        partial: [0; FRAME_BYTES],
        have: 0,
    });
    // The legs start where the first observation says they are.
    let mut control: Option<Control<CanFrame>> = None;
    loop {
        let Some(flags) = read_observation(&mut |buf| link.read_exact(buf), observation) else {
            halt()
        };
        if flags & 1 != 0 {
            stack.reset();
        }
        let Ok(outputs) = stack.infer(observation, work, row) else {
            halt()
        };
        // The window arrives after inference, into the bytes inference no longer needs.
        // SAFETY: `i8` and `u8` have the same size, alignment and validity.
        let bytes = unsafe { &mut *(work as *mut [i8; WORK_BYTES] as *mut [u8; WORK_BYTES]) };
        let Some(window) = bytes.get_mut(..window_bytes) else {
            halt()
        };
        link.read_exact(window);
        let Ok(record) = stack.decide(observation, &outputs, window) else {
            halt()
        };
        link.write(&record.to_bytes());
        let control = match &mut control {
            Some(control) => control,
            empty => {
                let started = empty.insert(Control::new(WHEELLEG, observation.legs()));
                if started.start_up(&mut board).is_err() {
                    halt()
                }
                started
            }
        };
        // An action the legs cannot take is not sent; a stopped loop holds the robot still
        // (the commander's safe stop) on every later period.
        let _ = control.step(&mut board, record.action());
    }
}
