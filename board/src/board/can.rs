//! The ODrive bus on FDCAN1: embassy's buffered FDCAN driver behind `embedded_can::nb::Can`
//! with the runtime's [`CanFrame`], and the control loop's [`Board`].
//!
//! The FDCAN's interrupt ([`super::CAN_PRIORITY`], above the control period) moves received
//! frames from the 3-deep hardware FIFO into a software queue and feeds queued frames to the
//! 3 transmit buffers as they leave, so a control period never waits on the bus: it drains
//! what arrived and queues its frames.

use core::num::{NonZeroU16, NonZeroU8};
use core::sync::atomic::{AtomicU32, Ordering};

use embassy_stm32::can::config::{GlobalFilter, NominalBitTiming, NonMatchingFilter, TxBufferMode};
use embassy_stm32::can::enums::BusErrorMode;
use embassy_stm32::can::{
    BufferedCan, BufferedCanReceiver, BufferedCanSender, CanConfigurator, Frame as HalFrame, RxBuf,
    TxBuf,
};
use embassy_stm32::{peripherals, Peri};
use embedded_can::{ErrorKind, Frame};
use wheelleg_controller::control::{Board, CAN_LINK_TIMEOUT_PERIODS};
use wheelleg_controller::link::Buffer;
use wheelleg_runtime::can::CanFrame;

use super::Irqs;

/// Frames the transmit queue holds: two periods of the most one period queues (the start-up's
/// 64), so a full queue means the bus has stopped taking frames, not a busy period.
pub const TX_QUEUE_FRAMES: usize = 2 * wheelleg_controller::control::TX_FRAMES;
/// Received frames the queue holds between two periods: a period brings one encoder estimate
/// per axis and some heartbeats (about 20 frames), the roll call 16 version answers.
pub const RX_QUEUE_FRAMES: usize = 64;

/// Nominal bit timing at 1 Mbit/s from the 170 MHz kernel clock: 5 cycles a quantum, 34 quanta
/// a bit (1 + 29 + 4), sampled at 88 % (CiA 301 recommends 87.5 % at 1 Mbit/s), resynchronising
/// by up to 4 quanta.
const PRESCALER: u16 = 5;
const SEG1_QUANTA: u8 = 29;
const SEG2_QUANTA: u8 = 4;
const SJW_QUANTA: u8 = 4;

static TX_QUEUE: Buffer<TxBuf<TX_QUEUE_FRAMES>> = Buffer::new(TxBuf::new());
static RX_QUEUE: Buffer<RxBuf<RX_QUEUE_FRAMES>> = Buffer::new(RxBuf::new());

/// The most CPU cycles (170 per microsecond) one control period has taken since boot, from its
/// start to its frames queued. Nothing in the firmware reads it; read it with a probe
/// (`probe-rs read b32 <address of BUSIEST_PERIOD_CYCLES>`) during bring-up: 10 ms are
/// 1,700,000 cycles.
#[no_mangle]
pub static BUSIEST_PERIOD_CYCLES: AtomicU32 = AtomicU32::new(0);

/// Bus errors (stuff, form, CRC, acknowledgement) the FDCAN reported since boot. Read it with a
/// probe like [`BUSIEST_PERIOD_CYCLES`]: it should stay still on a wired and terminated bus.
#[no_mangle]
pub static CAN_BUS_ERRORS: AtomicU32 = AtomicU32::new(0);

/// The peripheral refused a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CanFault {
    /// The transmit queue is full: the bus has not taken a frame for some periods.
    Backlog,
    /// A frame the FDCAN cannot carry (never one of the runtime's: 8 bytes at most).
    Frame,
}

impl embedded_can::Error for CanFault {
    fn kind(&self) -> ErrorKind {
        match self {
            CanFault::Backlog => ErrorKind::Overrun,
            CanFault::Frame => ErrorKind::Other,
        }
    }
}

/// FDCAN1 as `embedded_can::nb::Can`: frames out into the transmit queue, frames in from the
/// receive queue, neither ever waiting.
pub struct Fdcan {
    /// Owns the driver's state; dropping it would stop the queues.
    can: BufferedCan<'static, TX_QUEUE_FRAMES, RX_QUEUE_FRAMES>,
    tx: BufferedCanSender,
    rx: BufferedCanReceiver,
}

impl Fdcan {
    /// FDCAN1 on PA11 (RX) and PA12 (TX) at 1 Mbit/s, classic CAN, transmitting in queue order
    /// (Clear_Errors before Set_Axis_State, whatever their ids), taking every standard frame
    /// and no extended one (CANSimple's ids are 11-bit). `None` if called twice.
    pub fn new(
        fdcan: Peri<'static, peripherals::FDCAN1>,
        rx: Peri<'static, peripherals::PA11>,
        tx: Peri<'static, peripherals::PA12>,
    ) -> Option<Fdcan> {
        let (tx_queue, rx_queue) = (TX_QUEUE.take()?, RX_QUEUE.take()?);
        let mut configurator = CanConfigurator::new(fdcan, rx, tx, Irqs);
        let timing = NominalBitTiming {
            prescaler: NonZeroU16::new(PRESCALER)?,
            seg1: NonZeroU8::new(SEG1_QUANTA)?,
            seg2: NonZeroU8::new(SEG2_QUANTA)?,
            sync_jump_width: NonZeroU8::new(SJW_QUANTA)?,
        };
        let config = configurator
            .config()
            .set_nominal_bit_timing(timing)
            .set_tx_buffer_mode(TxBufferMode::Fifo)
            .set_global_filter(
                GlobalFilter::default().set_handle_extended_frames(NonMatchingFilter::Reject),
            );
        configurator.set_config(config);
        let can = configurator.into_normal_mode().buffered(tx_queue, rx_queue);
        let (tx, rx) = (can.writer(), can.reader());
        Some(Fdcan { can, tx, rx })
    }

    /// The FDCAN's error state (ISO 11898-1: error active, error passive, bus off).
    pub fn bus_error_mode(&self) -> BusErrorMode {
        self.can.properties().bus_error_mode()
    }
}

impl embedded_can::nb::Can for Fdcan {
    type Frame = CanFrame;
    type Error = CanFault;

    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, CanFault> {
        // The trait's constructors: the HAL's own take its header type.
        let out = if frame.is_remote_frame() {
            <HalFrame as Frame>::new_remote(frame.id(), frame.dlc())
        } else {
            <HalFrame as Frame>::new(frame.id(), frame.data())
        };
        let out = out.ok_or(nb::Error::Other(CanFault::Frame))?;
        // A full queue is an error, not `WouldBlock`: the control loop would spin on it in its
        // interrupt, above the decision, for as long as the bus stays dead.
        self.tx
            .try_write(out)
            .map(|()| None)
            .map_err(|_| nb::Error::Other(CanFault::Backlog))
    }

    fn receive(&mut self) -> nb::Result<CanFrame, CanFault> {
        loop {
            match self.rx.try_receive() {
                Ok(Ok(envelope)) => {
                    let frame = &envelope.frame;
                    let id = Frame::id(frame);
                    let frame = if Frame::is_remote_frame(frame) {
                        CanFrame::new_remote(id, Frame::dlc(frame))
                    } else {
                        CanFrame::new(id, Frame::data(frame))
                    };
                    if let Some(frame) = frame {
                        return Ok(frame);
                    }
                }
                // A bus error takes a slot of the queue; the frames after it still count.
                Ok(Err(_)) => {
                    // Only the control period writes it: a load and a store suffice.
                    let errors = CAN_BUS_ERRORS.load(Ordering::Relaxed);
                    CAN_BUS_ERRORS.store(errors.wrapping_add(1), Ordering::Relaxed);
                }
                Err(_) => return Err(nb::Error::WouldBlock),
            }
        }
    }
}

/// The control loop's board: FDCAN1, and the period's clock, which is the interrupt the loop
/// runs in (so [`Board::wait_for_tick`] only marks the period's start).
pub struct FdcanBoard {
    can: Fdcan,
    /// Consecutive periods begun with the FDCAN error passive or bus off.
    faulted_periods: u32,
    /// The cycle counter at the start of the current period.
    period_start_cycles: u32,
}

impl FdcanBoard {
    /// The board on `can`.
    pub fn new(can: Fdcan) -> FdcanBoard {
        FdcanBoard {
            can,
            faulted_periods: 0,
            period_start_cycles: 0,
        }
    }
}

impl Board for FdcanBoard {
    type Frame = CanFrame;
    type Can = Fdcan;

    fn can(&mut self) -> &mut Fdcan {
        &mut self.can
    }

    fn wait_for_tick(&mut self) {
        self.period_start_cycles = cortex_m::peripheral::DWT::cycle_count();
        // Error passive without recovering means the axes stopped acknowledging (no
        // transceiver, bus unpowered or open): the SLCAN adapter's silence on a real bus.
        self.faulted_periods = match self.can.bus_error_mode() {
            BusErrorMode::ErrorActive => 0,
            BusErrorMode::ErrorPassive | BusErrorMode::BusOff => {
                self.faulted_periods.saturating_add(1)
            }
        };
    }

    fn link_lost(&self) -> bool {
        self.faulted_periods >= CAN_LINK_TIMEOUT_PERIODS
    }

    fn tick_done(&mut self) {
        let cycles =
            cortex_m::peripheral::DWT::cycle_count().wrapping_sub(self.period_start_cycles);
        // Only the control period writes it: a load and a store suffice.
        if cycles > BUSIEST_PERIOD_CYCLES.load(Ordering::Relaxed) {
            BUSIEST_PERIOD_CYCLES.store(cycles, Ordering::Relaxed);
        }
    }
}
