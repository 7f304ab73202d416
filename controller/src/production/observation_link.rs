//! The observation link on UART 1: COBS frames from the perception computer decoded as their
//! bytes come, and the controller's messages sealed and sent back. The control period runs in
//! its interrupt meanwhile; the link only watches the clock for its own timeout.

use core::sync::atomic::Ordering;

use wheelleg_controller::wire::{self, FromController};

use crate::board::Uart;
use crate::period::PERIODS;

/// The observation link: COBS frames in, decoded into the receiver's buffer as they come.
pub(crate) struct Link {
    pub(crate) uart: Uart,
    pub(crate) frames: wire::FrameReceiver,
}

/// What waiting on the observation link brought.
pub(crate) enum Received {
    /// A decoded frame of this many bytes is in the buffer.
    Frame(usize),
    /// A frame that is no frame (bad COBS, too long).
    Bad,
    /// The period given as the wait's end began first.
    TimedOut,
}

impl Link {
    /// Reads bytes into `buf` until a frame ends or, with `until`, that control period
    /// begins.
    pub(crate) fn receive(&mut self, buf: &mut [u8], until: Option<u32>) -> Received {
        loop {
            // Every turn, not only when the link is quiet: a flood of bytes must not hide the
            // timeout.
            if until.is_some_and(reached) {
                return Received::TimedOut;
            }
            let Some(byte) = self.uart.try_read() else {
                continue;
            };
            match self.frames.feed(byte, buf) {
                wire::Fed::Nothing => {}
                wire::Fed::Frame(len) => return Received::Frame(len),
                wire::Fed::Bad => return Received::Bad,
            }
        }
    }

    /// Sends one message (a small one: all of the controller's are).
    pub(crate) fn send(&mut self, message: FromController) {
        let mut scratch = [0u8; 64];
        let mut frame = [0u8; 72];
        if let Ok(len) = wire::seal(message, &mut scratch, &mut frame) {
            self.uart.write(frame.get(..len).unwrap_or(&[]));
        }
    }
}

/// Whether control period `period` has begun (counts wrap after 497 days: compared by
/// difference).
pub(crate) fn reached(period: u32) -> bool {
    PERIODS.load(Ordering::Relaxed).wrapping_sub(period) < u32::MAX / 2
}
