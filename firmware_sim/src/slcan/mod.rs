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

mod client;
mod endpoint;
#[cfg(test)]
mod tests;

pub use client::{ClientStats, SlcanClient};
pub use endpoint::SlcanEndpoint;

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
