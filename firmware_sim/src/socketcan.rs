//! Linux SocketCAN transport (`vcan0`, `can0`), through the `socketcan` crate.
//!
//! Time is real here: the `now_us` arguments of [`Transport`] are ignored and frames arrive when
//! the kernel delivers them. The socket is non-blocking so a control loop never stalls on it.

use crate::bus::{BusError, Transport};
use socketcan::{CanSocket, Socket};
use std::io::ErrorKind;
use wheelleg_runtime::can::CanFrame;

/// A raw CAN socket bound to one interface.
pub struct SocketCan {
    socket: CanSocket,
    interface: String,
}

impl SocketCan {
    /// Opens `interface` (for example `vcan0`) in non-blocking mode.
    pub fn open(interface: &str) -> Result<SocketCan, BusError> {
        let socket = CanSocket::open(interface)?;
        socket.set_nonblocking(true)?;
        Ok(SocketCan {
            socket,
            interface: interface.to_owned(),
        })
    }

    /// The interface name.
    pub fn interface(&self) -> &str {
        &self.interface
    }
}

impl Transport for SocketCan {
    fn send(&mut self, frame: &CanFrame, _now_us: u64) -> Result<(), BusError> {
        use embedded_can::Frame;
        let out = if frame.is_remote_frame() {
            socketcan::CanFrame::new_remote(frame.id(), frame.dlc())
        } else {
            socketcan::CanFrame::new(frame.id(), frame.data())
        };
        let out = out.ok_or_else(|| {
            BusError::Io(std::io::Error::new(
                ErrorKind::InvalidInput,
                "frame not representable",
            ))
        })?;
        // A full transmit buffer on a non-blocking socket: retry briefly rather than lose a
        // setpoint silently.
        self.socket.write_frame_insist(&out)?;
        Ok(())
    }

    fn recv(&mut self, _now_us: u64) -> Result<Option<CanFrame>, BusError> {
        match self.socket.read_frame() {
            Ok(frame) => Ok(CanFrame::from_frame(&frame)),
            Err(e) if e.kind() == ErrorKind::WouldBlock => Ok(None),
            Err(e) => Err(BusError::Io(e)),
        }
    }
}

/// The first virtual CAN interface (`vcan*`) on this machine, if any: tests use it to decide
/// whether they can run against SocketCAN.
pub fn find_vcan() -> Option<String> {
    let entries = std::fs::read_dir("/sys/class/net").ok()?;
    let mut names: Vec<String> = entries
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("vcan"))
        .collect();
    names.sort();
    names.into_iter().next()
}
