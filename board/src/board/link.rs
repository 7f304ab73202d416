//! The observation link on USART2 (PA2 TX, PA3 RX: the ST-LINK's virtual COM port on the
//! NUCLEO-G474RE) at 2 Mbit/s: the DMA writes received bytes into a ring buffer in the
//! background, the decision side decodes its COBS frames from there (`wheelleg_controller::wire`,
//! as the QEMU image's link does) and sends the controller's messages back by DMA.

use embassy_stm32::mode::Async;
use embassy_stm32::usart::{self, RingBufferedUartRx, Uart, UartTx};
use embassy_stm32::{peripherals, Peri};
use embassy_time::{with_deadline, Duration, Instant};
use wheelleg_controller::link::Buffer;
use wheelleg_controller::wire::{self, FromController};

use super::Irqs;

/// The link's rate: USART2 divides its 170 MHz kernel clock by exactly 85.
pub const BAUD_RATE: u32 = 2_000_000;
/// The receive ring buffer: 10 ms of bytes at 2 Mbit/s, so a control period that delays the
/// decision side loses nothing of a frame arriving meanwhile (the fine window's 10.6 KB come in
/// 53 ms).
pub const RING_BYTES: usize = 2_048;
/// Bytes taken from the ring buffer at a time.
const CHUNK_BYTES: usize = 64;

static RING: Buffer<[u8; RING_BYTES]> = Buffer::new([0; RING_BYTES]);

/// What waiting on the link brought.
pub enum Received {
    /// A decoded frame of this many bytes is in the receiver's buffer.
    Frame(usize),
    /// A frame that is no frame (bad COBS, too long, a UART error or a ring buffer overrun).
    Bad,
    /// The wait's time ran out before a frame ended (a frame begun stays decoding).
    Quiet,
}

/// The observation link: COBS frames in, decoded into the receiver's buffer as they come.
pub struct ObservationLink {
    rx: RingBufferedUartRx<'static>,
    tx: UartTx<'static, Async>,
    frames: wire::FrameReceiver,
    chunk: [u8; CHUNK_BYTES],
    chunk_len: usize,
    chunk_at: usize,
}

impl ObservationLink {
    /// USART2 at [`BAUD_RATE`], 8N1, on PA3 (RX) and PA2 (TX), receiving through DMA1 channel 2
    /// into the ring buffer and sending through channel 1. `None` if called twice or the rate
    /// cannot be set.
    pub fn new(
        usart: Peri<'static, peripherals::USART2>,
        rx: Peri<'static, peripherals::PA3>,
        tx: Peri<'static, peripherals::PA2>,
        tx_dma: Peri<'static, peripherals::DMA1_CH1>,
        rx_dma: Peri<'static, peripherals::DMA1_CH2>,
    ) -> Option<ObservationLink> {
        let ring = RING.take()?;
        let mut config = usart::Config::default();
        config.baudrate = BAUD_RATE;
        let uart = Uart::new(usart, rx, tx, tx_dma, rx_dma, Irqs, config).ok()?;
        let (tx, rx) = uart.split();
        let mut rx = rx.into_ring_buffered(ring);
        rx.start_uart();
        Some(ObservationLink {
            rx,
            tx,
            frames: wire::FrameReceiver::new(),
            chunk: [0; CHUNK_BYTES],
            chunk_len: 0,
            chunk_at: 0,
        })
    }

    /// Decodes bytes into `buf` until a frame ends or `wait` has passed. The time is kept even
    /// while bytes come, so that a flood of them cannot hold off the caller's timeouts.
    pub async fn receive(&mut self, buf: &mut [u8], wait: Duration) -> Received {
        let deadline = Instant::now() + wait;
        loop {
            if self.chunk_at >= self.chunk_len {
                if Instant::now() >= deadline {
                    return Received::Quiet;
                }
                match with_deadline(deadline, self.rx.read(&mut self.chunk)).await {
                    Err(_) => return Received::Quiet,
                    Ok(Err(_)) => {
                        // Bytes were lost: the frame under way is broken. The next read
                        // restarts the reception.
                        self.frames.restart();
                        return Received::Bad;
                    }
                    Ok(Ok(read)) => (self.chunk_len, self.chunk_at) = (read, 0),
                }
            }
            let Some(&byte) = self.chunk.get(self.chunk_at) else {
                self.chunk_at = self.chunk_len;
                continue;
            };
            self.chunk_at += 1;
            match self.frames.feed(byte, buf) {
                wire::Fed::Nothing => {}
                wire::Fed::Frame(len) => return Received::Frame(len),
                wire::Fed::Bad => return Received::Bad,
            }
        }
    }

    /// Sends one message (a small one: all of the controller's are).
    pub async fn send(&mut self, message: FromController) {
        let mut scratch = [0u8; 64];
        let mut frame = [0u8; 72];
        if let Ok(len) = wire::seal(message, &mut scratch, &mut frame) {
            // A UART transmit error has no one to be reported to: the perception computer
            // notices the missing answer.
            let _ = self.tx.write(frame.get(..len).unwrap_or(&[])).await;
        }
    }
}
