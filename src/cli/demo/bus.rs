//! The demo's links to motors beyond the in-process bus (an SLCAN adapter over TCP, a
//! SocketCAN interface) and its bus log, written whole or not at all.

use std::io::Write;
use std::path::PathBuf;

/// How long connecting to an SLCAN adapter, and each answer of its open sequence, may take.
pub(super) const SLCAN_TIMEOUT_S: u64 = 3;

pub(super) fn open_slcan(
    endpoint: &str,
) -> Result<Box<dyn wheelleg_firmware_sim::bus::Transport>, String> {
    use wheelleg_firmware_sim::slcan::{EndpointSpec, SlcanClient};
    let spec: EndpointSpec = endpoint
        .parse()
        .map_err(|e| format!("--can slcan:{endpoint}: {e}"))?;
    if spec == EndpointSpec::Pty {
        return Err(format!(
            "--can slcan:{endpoint}: the demo reaches an SLCAN adapter by TCP only: \
             slcan:tcp:HOST:PORT"
        ));
    }
    let timeout = std::time::Duration::from_secs(SLCAN_TIMEOUT_S);
    match SlcanClient::connect(&spec, timeout) {
        Ok(client) => Ok(Box::new(client)),
        Err(e) => Err(format!(
            "cannot open the SLCAN adapter at {endpoint}: {e}. Start the motors behind one \
             with `firmware_sim --slcan {endpoint}`, or leave out --can to use the in-process bus"
        )),
    }
}

#[cfg(target_os = "linux")]
pub(super) fn open_socketcan(
    iface: &str,
) -> Result<Box<dyn wheelleg_firmware_sim::bus::Transport>, String> {
    match wheelleg_firmware_sim::socketcan::SocketCan::open(iface) {
        Ok(socket) => Ok(Box::new(socket)),
        Err(e) => Err(format!(
            "cannot open SocketCAN interface {iface}: {e}. Create a virtual bus with `ip link \
             add dev {iface} type vcan && ip link set up {iface}` and start the motors on it \
             with `firmware_sim --can {iface}`, or leave out --can to use the in-process bus"
        )),
    }
}

#[cfg(not(target_os = "linux"))]
pub(super) fn open_socketcan(
    iface: &str,
) -> Result<Box<dyn wheelleg_firmware_sim::bus::Transport>, String> {
    Err(format!(
        "cannot open SocketCAN interface {iface}: SocketCAN exists only on Linux; leave out \
         --can to use the in-process bus"
    ))
}

/// Writes into `dir/.name.tmp`; [`LogFile::commit`] renames it over `dir/name` once complete.
pub(super) struct LogFile {
    tmp: PathBuf,
    path: PathBuf,
}

impl LogFile {
    pub(super) fn create(path: PathBuf) -> Result<(LogFile, Box<dyn Write + Send>), String> {
        let name = path.file_name().map_or_else(
            || "bus.log".to_owned(),
            |n| n.to_string_lossy().into_owned(),
        );
        let tmp = path.with_file_name(format!(".{name}.tmp"));
        let file = std::fs::File::create(&tmp)
            .map_err(|e| format!("cannot create {}: {e}", tmp.display()))?;
        Ok((
            LogFile { tmp, path },
            Box::new(std::io::BufWriter::new(file)),
        ))
    }

    /// Removes the unfinished log (the loop never started), leaving any earlier one in place.
    pub(super) fn discard(self) {
        let _ = std::fs::remove_file(&self.tmp);
    }

    pub(super) fn commit(self) -> Result<(), String> {
        let fail = |e: std::io::Error| format!("cannot write {}: {e}", self.path.display());
        std::fs::File::open(&self.tmp)
            .and_then(|f| f.sync_all())
            .map_err(fail)?;
        std::fs::rename(&self.tmp, &self.path).map_err(fail)
    }
}
