//! A host's end of an SLCAN adapter on TCP: the closed loop's transport to the motors.

use super::*;

/// Counters of an [`SlcanClient`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct ClientStats {
    /// Frames sent to the adapter.
    pub frames_sent: u64,
    /// Frames received from the bus through the adapter.
    pub frames_received: u64,
    /// BEL replies: lines the adapter refused.
    pub refused: u64,
    /// Lines from the adapter that did not decode.
    pub malformed: u64,
}

/// The host's end: a [`Transport`] to an SLCAN adapter on TCP (`firmware_sim --slcan
/// tcp:HOST:PORT`, or a network CAN adapter that speaks SLCAN), for the controller side of the
/// closed loop. Connecting closes, sets 1 Mbit/s (`S8`) and opens the channel, each answered
/// before it returns; after that frames go out as `t` lines and come back from the adapter's
/// lines. Real time, non-blocking, as [`crate::socketcan::SocketCan`] is.
pub struct SlcanClient {
    stream: TcpStream,
    decoder: Decoder,
    inbound: VecDeque<CanFrame>,
    output: Vec<u8>,
    stats: ClientStats,
}

impl SlcanClient {
    /// Connects to the adapter at `spec` (TCP only) and opens its channel at 1 Mbit/s, waiting
    /// up to `timeout` for the connection and for each answer.
    pub fn connect(spec: &EndpointSpec, timeout: Duration) -> Result<SlcanClient, BusError> {
        let EndpointSpec::Tcp(address) = spec else {
            return Err(BusError::Io(std::io::Error::new(
                ErrorKind::Unsupported,
                "an SLCAN host connects by TCP only (tcp:HOST:PORT)",
            )));
        };
        let mut last_error = std::io::Error::new(
            ErrorKind::NotFound,
            format!("{address} resolves to no address"),
        );
        let mut stream = None;
        for candidate in address.to_socket_addrs()? {
            match TcpStream::connect_timeout(&candidate, timeout) {
                Ok(s) => {
                    stream = Some(s);
                    break;
                }
                Err(e) => last_error = e,
            }
        }
        let stream = stream.ok_or(BusError::Io(last_error))?;
        stream.set_nodelay(true)?;
        stream.set_read_timeout(Some(timeout))?;
        let mut client = SlcanClient {
            stream,
            decoder: Decoder::new(),
            inbound: VecDeque::new(),
            output: Vec::new(),
            stats: ClientStats::default(),
        };
        for command in [
            Command::Close,
            Command::BitRate(BitRate::Mbps1),
            Command::Open,
        ] {
            client.command(&command)?;
        }
        client.stream.set_nonblocking(true)?;
        Ok(client)
    }

    /// Counters.
    pub fn stats(&self) -> ClientStats {
        self.stats
    }

    /// Sends one command and waits (blocking, up to the read timeout) for its answer.
    fn command(&mut self, command: &Command) -> Result<(), BusError> {
        self.stream.write_all(encode_command(command).as_bytes())?;
        let mut byte = [0u8; 1];
        loop {
            match self.stream.read(&mut byte) {
                Ok(0) => return Err(closed()),
                Ok(_) => {}
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    return Err(BusError::Io(std::io::Error::new(
                        ErrorKind::TimedOut,
                        format!("no answer to SLCAN command {command:?}"),
                    )))
                }
                Err(e) => return Err(BusError::Io(e)),
            }
            match self.take(byte[0]) {
                Some(Reply::Ok) => return Ok(()),
                Some(Reply::Error) => {
                    return Err(BusError::Io(std::io::Error::other(format!(
                        "the SLCAN adapter refused {command:?}"
                    ))))
                }
                _ => {}
            }
        }
    }

    /// Decodes one byte from the adapter: frames are queued, replies handed back.
    fn take(&mut self, byte: u8) -> Option<Reply> {
        match self.decoder.feed_from_adapter(byte) {
            Ok(None) => None,
            Ok(Some(AdapterMessage::Frame { frame, .. })) => {
                self.stats.frames_received += 1;
                self.inbound.push_back(frame);
                None
            }
            Ok(Some(AdapterMessage::Reply(reply))) => {
                if reply == Reply::Error {
                    self.stats.refused += 1;
                }
                Some(reply)
            }
            Err(_) => {
                self.stats.malformed += 1;
                None
            }
        }
    }

    fn flush(&mut self) -> Result<(), BusError> {
        while !self.output.is_empty() {
            match self.stream.write(&self.output) {
                Ok(0) => return Err(closed()),
                Ok(n) => {
                    self.output.drain(..n);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(BusError::Io(e)),
            }
        }
        if self.output.len() > MAX_PENDING_BYTES {
            return Err(BusError::Io(std::io::Error::new(
                ErrorKind::WouldBlock,
                "the SLCAN adapter stopped reading: setpoints are backing up",
            )));
        }
        Ok(())
    }
}

fn closed() -> BusError {
    BusError::Io(std::io::Error::new(
        ErrorKind::ConnectionAborted,
        "the SLCAN adapter closed the connection",
    ))
}

impl Transport for SlcanClient {
    fn send(&mut self, frame: &CanFrame, _now_us: u64) -> Result<(), BusError> {
        let line = encode_frame(frame, None).map_err(|e| {
            BusError::Io(std::io::Error::new(ErrorKind::InvalidInput, e.to_string()))
        })?;
        self.output.extend_from_slice(line.as_bytes());
        self.stats.frames_sent += 1;
        self.flush()
    }

    fn recv(&mut self, _now_us: u64) -> Result<Option<CanFrame>, BusError> {
        if let Some(frame) = self.inbound.pop_front() {
            return Ok(Some(frame));
        }
        let mut buf = [0u8; 4096];
        loop {
            match self.stream.read(&mut buf) {
                Ok(0) => return Err(closed()),
                Ok(n) => {
                    for &byte in buf.get(..n).unwrap_or(&[]) {
                        self.take(byte);
                    }
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(BusError::Io(e)),
            }
        }
        self.flush()?;
        Ok(self.inbound.pop_front())
    }
}
