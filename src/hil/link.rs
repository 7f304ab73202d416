//! The host's end of the observation link: messages sealed and sent to the firmware, its
//! answers read back (`wire`, the firmware's own file).

use super::*;

impl Hil {
    pub(super) fn send(
        &mut self,
        message: ToController<'_>,
        corrupt: bool,
    ) -> Result<(), HilError> {
        let envelope = wire::Envelope {
            version: wire::VERSION,
            message,
        };
        let mut payload =
            postcard::to_allocvec(&envelope).map_err(|e| HilError::Protocol(e.to_string()))?;
        let crc = wire::CRC.checksum(&payload);
        payload.extend_from_slice(&crc.to_le_bytes());
        if corrupt {
            // One flipped bit in the payload: the checksum no longer matches.
            let middle = payload.len() / 2;
            if let Some(byte) = payload.get_mut(middle) {
                *byte ^= 0x10;
            }
        }
        let mut frame = cobs::encode_vec(&payload);
        frame.push(0);
        self.obs
            .write_all(&frame)
            .map_err(io("writing the observation link"))
    }

    /// The next message from the firmware.
    pub(super) fn receive(&mut self) -> Result<FromController, HilError> {
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        loop {
            if let Some(end) = self.received.iter().position(|&b| b == 0) {
                let mut frame: Vec<u8> = self.received.drain(..=end).collect();
                let len = cobs::decode_in_place(&mut frame).map_err(|_| {
                    HilError::Protocol("a frame from the firmware is not COBS".into())
                })?;
                return wire::open::<FromController>(&frame[..len]).map_err(|e| {
                    HilError::Protocol(format!("a frame from the firmware was refused: {e:?}"))
                });
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(HilError::Protocol(format!(
                    "the firmware did not answer within {} s",
                    ANSWER_TIMEOUT.as_secs()
                )));
            }
            self.obs
                .set_read_timeout(Some(left.min(Duration::from_secs(1))))
                .map_err(io("the observation link"))?;
            let mut buf = [0u8; 4096];
            match self.obs.read(&mut buf) {
                Ok(0) => {
                    return Err(HilError::Protocol(
                        "QEMU closed the observation link".into(),
                    ))
                }
                Ok(n) => self.received.extend_from_slice(&buf[..n]),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    if let Ok(Some(status)) = self.qemu.try_wait() {
                        return Err(HilError::Protocol(format!("QEMU exited: {status}")));
                    }
                }
                Err(e) => return Err(io("reading the observation link")(e)),
            }
        }
    }

    /// The next message that is not a refusal of a corrupt frame (those are counted).
    pub(super) fn answer(&mut self, rejected: &mut u32) -> Result<FromController, HilError> {
        loop {
            match self.receive()? {
                FromController::Rejected { .. } => *rejected += 1,
                other => return Ok(other),
            }
        }
    }
}
