//! The simulated bus behind an SLCAN (Lawicel ASCII) endpoint, as a USB-CAN adapter plugged
//! into the robot's bus would present it: python-can's `slcan` interface, SavvyCAN's LAWICEL
//! connection and `slcand` talk to the simulated axes as to real ones.
//!
//! Two endpoint forms ([`EndpointSpec`]):
//!
//! - `tcp:HOST:PORT`: a TCP server, one client at a time (python-can:
//!   `channel="socket://HOST:PORT"`). Port 0 picks a free port; [`SlcanEndpoint::describe`]
//!   names the one bound. A client that disconnects leaves the channel closed for the next.
//! - `pty` (Unix): a pseudo-terminal in raw mode; [`SlcanEndpoint::describe`] names its slave
//!   device (`/dev/pts/N`), which serial tools open like an adapter's `/dev/ttyACM0`.
//!
//! [`SlcanClient`] is the other end, a host's [`Transport`] to an adapter on TCP: the closed-loop
//! demo drives the motors through it (`wheelleg demo --can slcan:tcp:HOST:PORT`).
//!
//! [`SlcanAdapter`] is the adapter's behaviour, apart from any I/O: commands from the client
//! are answered (CR done, BEL refused, `z`/`Z` for a frame put on the bus), frames from it go to
//! the axes once the channel is open (`O`), and every frame on the bus (heartbeats, encoder
//! estimates, answers to requests) goes to the client as a `t…` line while it is open. As on a
//! Lawicel adapter, the bit rate (`Sn`, `sXXYY`) can only change while the channel is closed,
//! frames can only be sent while it is open and not listen-only (`L`), and switching between
//! `O` and `L` needs a `C` in between. Repeating the open command the channel is already in is
//! accepted (python-can sends `O` twice when it sets a bit rate), and so is `C` on a closed
//! channel, because every client sends it first to reset an adapter in an unknown state. The simulated bus carries frames at whatever bit rate
//! the client sets (the robot's is 1 Mbit/s, `S8`).
//!
//! Time is real, as with SocketCAN: the `now_us` of [`Transport`] only stamps frames when the
//! client asked for timestamps (`Z1`). I/O is non-blocking, so the simulation never waits for
//! a client; a client that reads too slowly loses frames, not the simulation its pace: beyond
//! [`MAX_PENDING_BYTES`] unsent, lines are dropped, counted, and flagged in the `F` reply
//! (receive queue full, data overrun), as an adapter's full queue would.

use crate::bus::{BusError, Transport};
use std::collections::VecDeque;
use std::fmt;
use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream, ToSocketAddrs};
use std::str::FromStr;
use std::time::Duration;
use wheelleg_runtime::can::slcan::{
    encode_command, encode_frame, encode_reply, status_flag, AdapterMessage, BitRate, Command,
    Decoder, Reply,
};
use wheelleg_runtime::can::CanFrame;

/// Bytes for the client that may wait unsent before frame lines are dropped: about 3,000
/// lines, 0.2 s of the axes' feedback.
pub const MAX_PENDING_BYTES: usize = 64 * 1024;
/// Frames from the client that may wait for the simulation before further ones are refused.
pub const MAX_INBOUND_FRAMES: usize = 1024;
/// The hardware and software version the `V` command reports.
pub const VERSION: Reply = Reply::Version {
    hardware: 1,
    software: 0,
};
/// The serial number the `N` command reports.
pub const SERIAL_NUMBER: [u8; 4] = *b"WLSM";

/// Where an SLCAN endpoint listens.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum EndpointSpec {
    /// `tcp:HOST:PORT`: a TCP server on this address.
    Tcp(String),
    /// `pty`: a new pseudo-terminal.
    Pty,
}

/// Why an endpoint specification does not parse.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SpecError(String);

impl fmt::Display for SpecError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for SpecError {}

impl FromStr for EndpointSpec {
    type Err = SpecError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s == "pty" {
            return Ok(EndpointSpec::Pty);
        }
        let Some(address) = s.strip_prefix("tcp:") else {
            return Err(SpecError(format!(
                "SLCAN endpoint '{s}' is neither tcp:HOST:PORT nor pty"
            )));
        };
        let port = address
            .rsplit_once(':')
            .filter(|(host, _)| !host.is_empty())
            .map(|(_, port)| port)
            .ok_or_else(|| {
                SpecError(format!(
                    "SLCAN endpoint '{s}' needs a host and a port: tcp:HOST:PORT (for example tcp:127.0.0.1:20108)"
                ))
            })?;
        port.parse::<u16>().map_err(|_| {
            SpecError(format!(
                "SLCAN endpoint '{s}': port '{port}' is not a number 0-65535"
            ))
        })?;
        Ok(EndpointSpec::Tcp(address.to_owned()))
    }
}

/// Whether the CAN channel is open, as the client last set it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChannelState {
    /// `C`: nothing reaches the bus or the client.
    Closed,
    /// `O`: frames both ways.
    Open,
    /// `L`: the client receives but may not transmit.
    ListenOnly,
}

/// Counters of one endpoint over all its clients.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct SlcanStats {
    /// Lines that decoded to a command.
    pub commands: u64,
    /// Malformed lines (answered with BEL).
    pub malformed: u64,
    /// Well-formed commands refused in the channel's state (answered with BEL).
    pub refused: u64,
    /// Frames from the client put on the simulated bus.
    pub frames_from_client: u64,
    /// Frames from the bus sent to the client.
    pub frames_to_client: u64,
    /// Frames from the bus dropped because the client read too slowly.
    pub frames_dropped: u64,
    /// TCP clients that connected.
    pub clients: u64,
}

/// An SLCAN adapter's state and replies for one client, without I/O.
#[derive(Clone, Debug)]
pub struct SlcanAdapter {
    decoder: Decoder,
    channel: ChannelState,
    bit_rate: Option<BitRate>,
    timestamps: bool,
    status_flags: u8,
    inbound: VecDeque<CanFrame>,
    output: Vec<u8>,
    stats: SlcanStats,
}

impl Default for SlcanAdapter {
    fn default() -> Self {
        SlcanAdapter::new()
    }
}

impl SlcanAdapter {
    /// A adapter with the channel closed, no timestamps, bit rate unset (the bus's own).
    pub fn new() -> SlcanAdapter {
        SlcanAdapter {
            decoder: Decoder::new(),
            channel: ChannelState::Closed,
            bit_rate: None,
            timestamps: false,
            status_flags: 0,
            inbound: VecDeque::new(),
            output: Vec::new(),
            stats: SlcanStats::default(),
        }
    }

    /// Starts over for a new client; the counters carry on.
    pub fn reset(&mut self) {
        let stats = self.stats;
        *self = SlcanAdapter::new();
        self.stats = stats;
    }

    /// The channel state.
    pub fn channel(&self) -> ChannelState {
        self.channel
    }

    /// The bit rate the client set with `Sn`, if it did.
    pub fn bit_rate(&self) -> Option<BitRate> {
        self.bit_rate
    }

    /// Counters.
    pub fn stats(&self) -> SlcanStats {
        self.stats
    }

    /// Takes bytes from the client: commands are answered into the output, frames queued for
    /// the bus.
    pub fn receive_bytes(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            match self.decoder.feed(byte) {
                Ok(None) => {}
                Ok(Some(command)) => {
                    self.stats.commands += 1;
                    let reply = self.execute(command);
                    if reply == Reply::Error {
                        self.stats.refused += 1;
                    }
                    self.reply(reply);
                }
                Err(_) => {
                    self.stats.malformed += 1;
                    self.reply(Reply::Error);
                }
            }
        }
    }

    fn execute(&mut self, command: Command) -> Reply {
        let closed = self.channel == ChannelState::Closed;
        match command {
            // python-can sends `O` twice when it sets a bit rate (once after `Sn`, once more
            // on opening): opening the channel as it already is, is done. Switching between
            // normal and listen-only needs a `C` first.
            Command::Open if self.channel == ChannelState::Open => Reply::Ok,
            Command::ListenOnly if self.channel == ChannelState::ListenOnly => Reply::Ok,
            Command::Open | Command::ListenOnly if !closed => Reply::Error,
            Command::Open => {
                self.channel = ChannelState::Open;
                Reply::Ok
            }
            Command::ListenOnly => {
                self.channel = ChannelState::ListenOnly;
                Reply::Ok
            }
            Command::Close => {
                self.channel = ChannelState::Closed;
                Reply::Ok
            }
            Command::BitRate(_) | Command::BitTiming { .. } if !closed => Reply::Error,
            Command::BitRate(rate) => {
                self.bit_rate = Some(rate);
                Reply::Ok
            }
            Command::BitTiming { .. } => Reply::Ok,
            Command::Frame { frame, .. } => {
                if self.channel != ChannelState::Open || self.inbound.len() >= MAX_INBOUND_FRAMES {
                    return Reply::Error;
                }
                self.inbound.push_back(frame);
                self.stats.frames_from_client += 1;
                Reply::Transmitted {
                    extended: embedded_can::Frame::is_extended(&frame),
                }
            }
            Command::Version => VERSION,
            Command::SerialNumber => Reply::SerialNumber(SERIAL_NUMBER),
            Command::StatusFlags => Reply::StatusFlags(std::mem::take(&mut self.status_flags)),
            Command::Timestamps(on) => {
                self.timestamps = on;
                Reply::Ok
            }
        }
    }

    fn reply(&mut self, reply: Reply) {
        // Replies are a few bytes and the client waits for them: they are never dropped.
        self.output
            .extend_from_slice(encode_reply(&reply).as_bytes());
    }

    /// The next frame from the client for the bus.
    pub fn next_frame(&mut self) -> Option<CanFrame> {
        self.inbound.pop_front()
    }

    /// Hands a frame on the bus to the client, if its channel is open (returns whether it was
    /// queued).
    pub fn frame_to_client(&mut self, frame: &CanFrame, now_us: u64) -> bool {
        if self.channel == ChannelState::Closed {
            return false;
        }
        let timestamp_ms = self.timestamps.then_some(((now_us / 1000) % 60_000) as u16);
        let Ok(line) = encode_frame(frame, timestamp_ms) else {
            return false;
        };
        if self.output.len() + line.as_bytes().len() > MAX_PENDING_BYTES {
            self.stats.frames_dropped += 1;
            self.status_flags |= status_flag::RX_QUEUE_FULL | status_flag::DATA_OVERRUN;
            return false;
        }
        self.output.extend_from_slice(line.as_bytes());
        self.stats.frames_to_client += 1;
        true
    }

    /// Bytes waiting for the client.
    pub fn pending_output(&self) -> &[u8] {
        &self.output
    }

    /// Drops the first `n` waiting bytes (they were written).
    pub fn consume_output(&mut self, n: usize) {
        self.output.drain(..n.min(self.output.len()));
    }
}

/// The byte stream of an endpoint.
enum Link {
    Tcp {
        listener: TcpListener,
        client: Option<TcpStream>,
    },
    #[cfg(unix)]
    Pty {
        master: std::fs::File,
        // Held open so the master never reads EIO between clients, and keeps the raw mode set.
        _slave: std::os::fd::OwnedFd,
        path: std::path::PathBuf,
    },
}

/// An SLCAN endpoint serving the simulated bus: a [`Transport`] whose other side is a client
/// speaking SLCAN.
pub struct SlcanEndpoint {
    link: Link,
    adapter: SlcanAdapter,
}

impl SlcanEndpoint {
    /// Binds the TCP address or creates the pseudo-terminal.
    pub fn open(spec: &EndpointSpec) -> Result<SlcanEndpoint, BusError> {
        let link = match spec {
            EndpointSpec::Tcp(address) => {
                let listener = TcpListener::bind(address.as_str())?;
                listener.set_nonblocking(true)?;
                Link::Tcp {
                    listener,
                    client: None,
                }
            }
            #[cfg(unix)]
            EndpointSpec::Pty => open_pty()?,
            #[cfg(not(unix))]
            EndpointSpec::Pty => {
                return Err(BusError::Io(std::io::Error::new(
                    ErrorKind::Unsupported,
                    "SLCAN on a pseudo-terminal needs a Unix system; use tcp:HOST:PORT",
                )))
            }
        };
        Ok(SlcanEndpoint {
            link,
            adapter: SlcanAdapter::new(),
        })
    }

    /// What a client connects to: `tcp:HOST:PORT` with the port bound, or the pty's device path.
    pub fn describe(&self) -> String {
        match &self.link {
            Link::Tcp { listener, .. } => match listener.local_addr() {
                Ok(address) => format!("tcp:{address}"),
                Err(_) => "tcp:(unknown address)".to_owned(),
            },
            #[cfg(unix)]
            Link::Pty { path, .. } => path.display().to_string(),
        }
    }

    /// The adapter state and counters.
    pub fn adapter(&self) -> &SlcanAdapter {
        &self.adapter
    }

    /// Accepts a waiting client, reads what it sent, writes what is pending.
    fn poll(&mut self) -> Result<(), BusError> {
        let mut buf = [0u8; 4096];
        match &mut self.link {
            Link::Tcp { listener, client } => {
                loop {
                    match listener.accept() {
                        Ok((stream, peer)) if client.is_none() => {
                            stream.set_nonblocking(true)?;
                            // Lines are small and latency matters more than packing them.
                            stream.set_nodelay(true)?;
                            eprintln!("firmware_sim: SLCAN client {peer} connected");
                            *client = Some(stream);
                            self.adapter.reset();
                            self.adapter.stats.clients += 1;
                        }
                        Ok((stream, peer)) => {
                            eprintln!(
                                "firmware_sim: SLCAN client {peer} refused: another client is connected"
                            );
                            drop(stream);
                        }
                        Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                        Err(e) => return Err(BusError::Io(e)),
                    }
                }
                let Some(stream) = client else {
                    return Ok(());
                };
                let mut gone = false;
                loop {
                    match stream.read(&mut buf) {
                        Ok(0) => {
                            gone = true;
                            break;
                        }
                        Ok(n) => self.adapter.receive_bytes(buf.get(..n).unwrap_or(&[])),
                        Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                        Err(e) if e.kind() == ErrorKind::Interrupted => {}
                        Err(_) => {
                            gone = true;
                            break;
                        }
                    }
                }
                if !gone && write_pending(stream, &mut self.adapter).is_err() {
                    gone = true;
                }
                if gone {
                    eprintln!("firmware_sim: SLCAN client disconnected");
                    *client = None;
                    self.adapter.reset();
                }
                Ok(())
            }
            #[cfg(unix)]
            Link::Pty { master, .. } => {
                loop {
                    match master.read(&mut buf) {
                        Ok(0) => break,
                        Ok(n) => self.adapter.receive_bytes(buf.get(..n).unwrap_or(&[])),
                        Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                        Err(e) if e.kind() == ErrorKind::Interrupted => {}
                        Err(e) => return Err(BusError::Io(e)),
                    }
                }
                write_pending(master, &mut self.adapter).map_err(BusError::Io)
            }
        }
    }
}

/// Writes as much pending output as the stream takes now.
fn write_pending<W: Write>(stream: &mut W, adapter: &mut SlcanAdapter) -> std::io::Result<()> {
    while !adapter.pending_output().is_empty() {
        match stream.write(adapter.pending_output()) {
            Ok(0) => return Err(ErrorKind::WriteZero.into()),
            Ok(n) => adapter.consume_output(n),
            Err(e) if e.kind() == ErrorKind::WouldBlock => break,
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

#[cfg(unix)]
fn open_pty() -> Result<Link, BusError> {
    use nix::fcntl::{fcntl, FcntlArg, OFlag};
    use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
    let io = |e: nix::Error| BusError::Io(std::io::Error::from(e));
    let pty = nix::pty::openpty(None, None).map_err(io)?;
    // Raw: no echo, no CR to LF translation, no line editing; SLCAN bytes pass unchanged.
    let mut termios = tcgetattr(&pty.slave).map_err(io)?;
    cfmakeraw(&mut termios);
    tcsetattr(&pty.slave, SetArg::TCSANOW, &termios).map_err(io)?;
    let flags = OFlag::from_bits_truncate(fcntl(&pty.master, FcntlArg::F_GETFL).map_err(io)?);
    fcntl(&pty.master, FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK)).map_err(io)?;
    let path = nix::unistd::ttyname(&pty.slave).map_err(io)?;
    Ok(Link::Pty {
        master: std::fs::File::from(pty.master),
        _slave: pty.slave,
        path,
    })
}

impl Transport for SlcanEndpoint {
    fn send(&mut self, frame: &CanFrame, now_us: u64) -> Result<(), BusError> {
        self.adapter.frame_to_client(frame, now_us);
        Ok(())
    }

    fn recv(&mut self, _now_us: u64) -> Result<Option<CanFrame>, BusError> {
        if let Some(frame) = self.adapter.next_frame() {
            return Ok(Some(frame));
        }
        self.poll()?;
        Ok(self.adapter.next_frame())
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    fn adapter_after(bytes: &[u8]) -> SlcanAdapter {
        let mut s = SlcanAdapter::new();
        s.receive_bytes(bytes);
        s
    }

    #[test]
    fn endpoint_specs_parse_or_say_what_is_wrong() {
        assert_eq!(
            "tcp:127.0.0.1:20108".parse(),
            Ok(EndpointSpec::Tcp("127.0.0.1:20108".into()))
        );
        assert_eq!(
            "tcp:[::1]:0".parse(),
            Ok(EndpointSpec::Tcp("[::1]:0".into()))
        );
        assert_eq!("pty".parse(), Ok(EndpointSpec::Pty));
        let err = |s: &str| s.parse::<EndpointSpec>().unwrap_err().to_string();
        assert!(err("serial").contains("neither tcp:HOST:PORT nor pty"));
        assert!(err("tcp:20108").contains("needs a host and a port"));
        assert!(err("tcp:localhost:http").contains("port 'http' is not a number"));
        assert!(err("tcp:localhost:70000").contains("port '70000'"));
    }

    #[test]
    fn python_can_open_sequence_opens_the_channel() {
        // python-can with bitrate=1000000: close, bit rate, an empty line, open, open again.
        let s = adapter_after(b"C\rS8\r\rO\rO\r");
        assert_eq!(s.channel(), ChannelState::Open);
        assert_eq!(s.bit_rate(), Some(BitRate::Mbps1));
        assert_eq!(s.pending_output(), b"\r\r\r\r");
        assert_eq!(s.stats().malformed + s.stats().refused, 0);
    }

    #[test]
    fn frames_pass_only_while_the_channel_is_open() {
        let mut s = adapter_after(b"t1A20\r");
        assert_eq!(s.next_frame(), None);
        assert_eq!(s.pending_output(), [0x07]);
        assert_eq!(s.stats().refused, 1);
        let hb = CanFrame::standard(0x1A1, &[0, 0, 0, 0, 1, 0, 0, 0]).unwrap();
        assert!(!s.frame_to_client(&hb, 0));
        s.consume_output(1);
        s.receive_bytes(b"O\rt1A20\rT000001A20\r");
        assert_eq!(s.pending_output(), b"\rz\rZ\r");
        assert_eq!(s.next_frame(), CanFrame::standard(0x1A2, &[]));
        assert!(s.next_frame().unwrap().raw_id() == 0x1A2);
        s.consume_output(5);
        assert!(s.frame_to_client(&hb, 0));
        assert_eq!(s.pending_output(), b"t1A180000000001000000\r");
        assert_eq!(s.stats().frames_from_client, 2);
        assert_eq!(s.stats().frames_to_client, 1);
    }

    #[test]
    fn listen_only_receives_but_refuses_to_transmit() {
        let mut s = adapter_after(b"L\rt1A20\r");
        assert_eq!(s.channel(), ChannelState::ListenOnly);
        assert_eq!(s.pending_output(), b"\r\x07");
        assert_eq!(s.next_frame(), None);
        let hb = CanFrame::standard(0x1A1, &[0; 8]).unwrap();
        assert!(s.frame_to_client(&hb, 0));
    }

    #[test]
    fn state_rules_match_a_lawicel_adapter() {
        // C when closed is fine; O twice too; L on an open channel, S and s while open are
        // refused; after C they are accepted; O on a listen-only channel is refused.
        let s = adapter_after(b"C\rO\rO\rL\rS6\rs031C\rC\rS6\rs031C\rL\rL\rO\r");
        assert_eq!(s.pending_output(), b"\r\r\r\x07\x07\x07\r\r\r\r\r\x07");
        assert_eq!(s.bit_rate(), Some(BitRate::Kbps500));
        assert_eq!(s.stats().refused, 4);
        assert_eq!(s.channel(), ChannelState::ListenOnly);
    }

    #[test]
    fn version_serial_number_and_status_flags_answer() {
        let mut s = adapter_after(b"V\rN\rF\r");
        assert_eq!(s.pending_output(), b"V0100\rNWLSM\rF00\r");
        s.consume_output(usize::MAX);
        s.receive_bytes(b"O\r");
        s.consume_output(usize::MAX);
        // A client that never reads: the queue fills, frames are dropped and flagged.
        let hb = CanFrame::standard(0x1A1, &[0; 8]).unwrap();
        let mut queued = 0;
        for _ in 0..5000 {
            queued += usize::from(s.frame_to_client(&hb, 0));
        }
        assert_eq!(queued, MAX_PENDING_BYTES / 22);
        assert_eq!(s.stats().frames_dropped, 5000 - queued as u64);
        s.consume_output(usize::MAX);
        s.receive_bytes(b"F\rF\r");
        assert_eq!(s.pending_output(), b"F09\rF00\r");
    }

    #[test]
    fn malformed_lines_get_bel_and_are_counted() {
        let s = adapter_after(b"garbage\rt1239\rt8000\rt1232AA\rT1230\rS9\r\x00\xff\r");
        assert_eq!(s.pending_output(), [0x07; 7]);
        assert_eq!(s.stats().malformed, 7);
        assert_eq!(s.stats().commands, 0);
    }

    #[test]
    fn a_client_opens_the_channel_and_exchanges_frames_with_the_endpoint() {
        let spec = EndpointSpec::Tcp("127.0.0.1:0".into());
        let mut endpoint = SlcanEndpoint::open(&spec).unwrap();
        let address = endpoint.describe().strip_prefix("tcp:").unwrap().to_owned();
        let serve = std::thread::spawn(move || {
            let hb = CanFrame::standard(0x1A1, &[0, 0, 0, 0, 8, 0, 0, 0]).unwrap();
            let mut got = None;
            for _ in 0..5000 {
                if let Some(frame) = endpoint.recv(0).unwrap() {
                    got = Some(frame);
                }
                if got.is_some() {
                    endpoint.send(&hb, 0).unwrap();
                    endpoint.recv(0).unwrap();
                    std::thread::sleep(Duration::from_millis(20));
                    break;
                }
                std::thread::sleep(Duration::from_millis(1));
            }
            (got, endpoint.adapter().stats())
        });
        let mut client =
            SlcanClient::connect(&EndpointSpec::Tcp(address), Duration::from_secs(5)).unwrap();
        let estop = CanFrame::standard(0x1A2, &[]).unwrap();
        client.send(&estop, 0).unwrap();
        let mut heard = None;
        for _ in 0..5000 {
            if let Some(frame) = client.recv(0).unwrap() {
                heard = Some(frame);
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        let (got, stats) = serve.join().unwrap();
        assert_eq!(got, Some(estop));
        assert_eq!(heard.map(|f| f.raw_id()), Some(0x1A1));
        assert_eq!((stats.malformed, stats.refused, stats.clients), (0, 0, 1));
        assert_eq!(client.stats().refused, 0);
        let no_one = SlcanClient::connect(
            &EndpointSpec::Tcp("127.0.0.1:1".into()),
            Duration::from_secs(1),
        );
        assert!(no_one.is_err());
    }

    #[test]
    fn timestamps_are_milliseconds_modulo_a_minute() {
        let mut s = adapter_after(b"Z1\rO\r");
        s.consume_output(usize::MAX);
        let f = CanFrame::standard(0x001, &[]).unwrap();
        s.frame_to_client(&f, 61_234_999);
        assert_eq!(s.pending_output(), b"t001004D2\r");
    }
}
