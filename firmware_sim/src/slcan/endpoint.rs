//! The adapter's endpoint: a TCP server or a pseudo-terminal in front of the simulated bus.

use super::*;

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
