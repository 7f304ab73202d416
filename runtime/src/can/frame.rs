//! A plain classic-CAN frame that implements [`embedded_can::Frame`].
//!
//! Everything in [`crate::can`] is generic over `embedded_can::Frame`, so on a microcontroller
//! the HAL's own frame type is used directly. This one exists for hosts and tests (the
//! in-process bus, log replay) where no HAL is around; it is `Copy`, 16 bytes, and never
//! allocates.

use embedded_can::{Frame, Id, StandardId};

/// Largest classic-CAN payload.
pub const MAX_DATA_LEN: usize = 8;

/// A classic CAN 2.0 frame (standard or extended id, data or remote).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CanFrame {
    id: Id,
    remote: bool,
    dlc: u8,
    data: [u8; MAX_DATA_LEN],
}

impl CanFrame {
    /// A data frame with an 11-bit id; `None` if the id is over 0x7FF or the payload over 8 bytes.
    pub fn standard(raw_id: u16, data: &[u8]) -> Option<CanFrame> {
        CanFrame::new(StandardId::new(raw_id)?, data)
    }

    /// The raw id bits (11 or 29 of them).
    pub fn raw_id(&self) -> u32 {
        match self.id {
            Id::Standard(id) => u32::from(id.as_raw()),
            Id::Extended(id) => id.as_raw(),
        }
    }

    /// Converts any other `embedded_can` frame (for example a SocketCAN one) into this type.
    pub fn from_frame<F: Frame>(frame: &F) -> Option<CanFrame> {
        if frame.is_remote_frame() {
            CanFrame::new_remote(frame.id(), frame.dlc())
        } else {
            CanFrame::new(frame.id(), frame.data())
        }
    }
}

impl Frame for CanFrame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        if data.len() > MAX_DATA_LEN {
            return None;
        }
        let mut buf = [0u8; MAX_DATA_LEN];
        buf.get_mut(..data.len())?.copy_from_slice(data);
        Some(CanFrame {
            id: id.into(),
            remote: false,
            dlc: data.len() as u8,
            data: buf,
        })
    }

    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        if dlc > MAX_DATA_LEN {
            return None;
        }
        Some(CanFrame {
            id: id.into(),
            remote: true,
            dlc: dlc as u8,
            data: [0; MAX_DATA_LEN],
        })
    }

    fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }

    fn is_remote_frame(&self) -> bool {
        self.remote
    }

    fn id(&self) -> Id {
        self.id
    }

    fn dlc(&self) -> usize {
        usize::from(self.dlc)
    }

    fn data(&self) -> &[u8] {
        // A remote frame carries a DLC but no payload bytes.
        let len = if self.remote { 0 } else { self.dlc() };
        self.data.get(..len).unwrap_or(&[])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn payloads_over_eight_bytes_and_ids_over_11_bits_are_refused() {
        assert!(CanFrame::standard(0x7FF, &[0; 8]).is_some());
        assert!(CanFrame::standard(0x800, &[]).is_none());
        assert!(CanFrame::standard(0x10, &[0; 9]).is_none());
        let remote = CanFrame::new_remote(StandardId::new(0x29).unwrap(), 8).unwrap();
        assert_eq!(remote.dlc(), 8);
        assert!(remote.data().is_empty());
    }
}
