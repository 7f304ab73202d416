//! The NUCLEO-G474RE's hardware as the app uses it: the clocks, the interrupts' priorities and
//! bindings, the CAN bus to the ODrive axes ([`can`]) and the observation link ([`link`]).
//!
//! | what | peripheral | pins (NUCLEO-G474RE) |
//! |---|---|---|
//! | ODrive CAN bus, 1 Mbit/s classic CAN | FDCAN1 | PA11 RX, PA12 TX (CN10 14, 12) to a 3.3 V transceiver |
//! | observation link, 2 Mbit/s 8N1 | USART2, DMA1 channels 1 (TX) and 2 (RX) | PA2 TX, PA3 RX (the ST-LINK's virtual COM port) |
//! | the 100 Hz control period | TIM2 (embassy's time driver) waking the UART5 interrupt | |

pub mod can;
pub mod link;

use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::time::Hertz;
use embassy_stm32::{bind_interrupts, dma, interrupt, peripherals, usart};

/// The HSE crystal of the NUCLEO-G474RE (X3). CAN at 1 Mbit/s needs a crystal's accuracy: the
/// HSI's 1 % is outside the bus's tolerance.
pub const HSE_HZ: u32 = 24_000_000;
/// SYSCLK, HCLK, PCLK1 and PCLK2: the part's maximum (range 1 boost mode).
pub const SYSCLK_HZ: u32 = 170_000_000;

/// Above the control period: the FDCAN's receive FIFO holds 3 frames (0.4 ms of a busy bus at
/// 1 Mbit/s), so its interrupt must drain it even while a period runs.
pub const CAN_PRIORITY: Priority = Priority::P1;
/// The control period's executor: above everything but the CAN interrupt and the time driver
/// (TIM2, left at P0, the highest, so the period's wake-up is never late).
pub const CONTROL_PRIORITY: Priority = Priority::P2;
/// The observation link's UART and DMA: they only wake the decision in thread mode, so the
/// control period may delay them (the DMA ring buffer takes the bytes meanwhile).
pub const LINK_PRIORITY: Priority = Priority::P3;

/// The interrupt the control period's executor runs in: UART5, unused on this board.
pub const CONTROL_INTERRUPT: interrupt::Interrupt = interrupt::UART5;

bind_interrupts!(
    /// The interrupts of the drivers: FDCAN1's two lines, USART2 and its DMA channels.
    pub struct Irqs {
        FDCAN1_IT0 => embassy_stm32::can::IT0InterruptHandler<peripherals::FDCAN1>;
        FDCAN1_IT1 => embassy_stm32::can::IT1InterruptHandler<peripherals::FDCAN1>;
        USART2 => usart::InterruptHandler<peripherals::USART2>;
        DMA1_CHANNEL1 => dma::InterruptHandler<peripherals::DMA1_CH1>;
        DMA1_CHANNEL2 => dma::InterruptHandler<peripherals::DMA1_CH2>;
    }
);

/// The clocks: SYSCLK 170 MHz from the 24 MHz HSE through the PLL (24 / 6 x 85 / 2), every bus
/// undivided; FDCAN1 clocked from PCLK1 (170 MHz: 34 quanta of 5 cycles per bit at 1 Mbit/s).
pub fn config() -> embassy_stm32::Config {
    use embassy_stm32::rcc::{
        mux, Hse, HseMode, Pll, PllMul, PllPreDiv, PllRDiv, PllSource, Sysclk,
    };
    let mut config = embassy_stm32::Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(HSE_HZ),
        mode: HseMode::Oscillator,
    });
    config.rcc.pll = Some(Pll {
        source: PllSource::HSE,
        prediv: PllPreDiv::DIV6,
        mul: PllMul::MUL85,
        divp: None,
        divq: None,
        divr: Some(PllRDiv::DIV2),
    });
    config.rcc.sys = Sysclk::PLL1_R;
    config.rcc.boost = true;
    config.rcc.mux.fdcansel = mux::Fdcansel::PCLK1;
    // The G4's DMA is the "BDMA" kind in embassy's terms.
    config.bdma_interrupt_priority = LINK_PRIORITY;
    config
}

/// Sets the drivers' interrupts to their priorities ([`CAN_PRIORITY`], [`LINK_PRIORITY`]);
/// their drivers enable them at the reset priority, the highest.
pub fn set_priorities() {
    interrupt::FDCAN1_IT0.set_priority(CAN_PRIORITY);
    interrupt::FDCAN1_IT1.set_priority(CAN_PRIORITY);
    interrupt::USART2.set_priority(LINK_PRIORITY);
}

/// Starts the Cortex-M4's cycle counter, which times the control period
/// ([`can::BUSIEST_PERIOD_CYCLES`]).
pub fn start_cycle_counter(mut core: cortex_m::Peripherals) {
    core.DCB.enable_trace();
    core.DWT.enable_cycle_counter();
}
