//! What the loop needs of a board, and when a board calls its CAN link lost.

use embedded_can::nb::Can;
use embedded_can::Frame;

/// An adapter not heard from for this many control periods is lost (its status poll of each
/// period unanswered): 50 ms, the axes' health timeout.
pub const CAN_LINK_TIMEOUT_PERIODS: u32 = 5;

/// What the control loop needs of a board: its CAN peripheral and the control period's clock.
pub trait Board {
    /// The CAN peripheral's frame type.
    type Frame: Frame;
    /// The CAN peripheral (a HAL's bxCAN or FDCAN driver, or QEMU's replay).
    type Can: Can<Frame = Self::Frame>;
    /// The CAN peripheral.
    fn can(&mut self) -> &mut Self::Can;
    /// Starts the next control period: a board whose periods come from a loop waits for the
    /// period's start here; one whose periods run in the timer's interrupt is already there.
    fn wait_for_tick(&mut self);
    /// Whether the link to the CAN bus is lost (an SLCAN adapter that stopped answering; a
    /// peripheral on the board's own bus never is).
    fn link_lost(&self) -> bool {
        false
    }
    /// The period's frames go out now (feedback read, setpoints computed): a board that
    /// stamps them with the time reads its clock here.
    fn sending(&mut self) {}
    /// The period's work is done (its frames are sent): a board that measures the period's
    /// cost reads its clock here.
    fn tick_done(&mut self) {}
}
