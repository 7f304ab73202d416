//! The observation link on UART 1: COBS frames from the perception computer decoded as their
//! bytes come, the controller's messages sealed and sent back, and the control period kept
//! running (the robot held) while a frame is awaited.

use wheelleg_controller::control::{Control, StopReason};
use wheelleg_controller::wire::{self, FromController};
use wheelleg_runtime::can::CanFrame;

use crate::board::{SlcanBoard, Uart};

/// The observation link: COBS frames in, decoded into the receiver's buffer as they come.
pub(crate) struct Link {
    pub(crate) uart: Uart,
    pub(crate) cobs: cobs::DecoderState,
    pub(crate) len: usize,
    pub(crate) too_long: bool,
}

/// What waiting on the observation link brought.
pub(crate) enum Received {
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
    pub(crate) fn receive(
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
    pub(crate) fn send(&mut self, message: FromController) {
        let mut scratch = [0u8; 64];
        let mut frame = [0u8; 72];
        if let Ok(len) = wire::seal(message, &mut scratch, &mut frame) {
            self.uart.write(frame.get(..len).unwrap_or(&[]));
        }
    }
}
