//! Starting the firmware in the loop: QEMU with its instruction clock, its two serial links
//! and its monitor on sockets the host listens on, the emulated clock's FIFO, and the thread
//! that plays the CAN adapter.

use super::*;

/// QEMU's instruction clock for `clock`: in lockstep 1 ns per instruction with idle time
/// skipped, so that a period costs only what the firmware executes; on the emulated clock
/// 4 ns per instruction (250 M instructions/s, the power of two nearest above the reference
/// part's 170 MHz at about one cycle per instruction), idle time skipped too: the firmware's
/// periods wait for the host only in the adapter's FIFO, which costs the clock nothing.
fn icount(clock: PlantClock) -> &'static str {
    match clock {
        PlantClock::Lockstep => "shift=0,sleep=off",
        PlantClock::Emulated => "shift=2,sleep=off",
    }
}

fn listener() -> Result<(TcpListener, u16), HilError> {
    let listener = TcpListener::bind("127.0.0.1:0").map_err(io("listening for QEMU"))?;
    let port = listener
        .local_addr()
        .map_err(io("listening for QEMU"))?
        .port();
    Ok((listener, port))
}

/// Accepts QEMU's connection, or fails when QEMU exits first.
fn accept(listener: &TcpListener, qemu: &mut Child, what: &str) -> Result<TcpStream, HilError> {
    listener
        .set_nonblocking(true)
        .map_err(io("listening for QEMU"))?;
    let started = Instant::now();
    loop {
        match listener.accept() {
            Ok((stream, _)) => {
                stream.set_nonblocking(false).map_err(io(what))?;
                stream.set_nodelay(true).map_err(io(what))?;
                return Ok(stream);
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if let Ok(Some(status)) = qemu.try_wait() {
                    return Err(HilError::Io(format!(
                        "QEMU exited ({status}) before connecting its {what}"
                    )));
                }
                if started.elapsed() > Duration::from_secs(20) {
                    return Err(HilError::Io(format!("QEMU did not connect its {what}")));
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => return Err(io(what)(e)),
        }
    }
}

impl Hil {
    /// Starts `image` in QEMU with the motors of `robot` (the robot its weights were trained
    /// for: its geometry and node map) and their legs at `start`, the motors' time on `clock`
    /// (an image built for it: [`image_for`]).
    pub fn start(
        image: &Path,
        robot: &Robot,
        start: LegConfig,
        clock: PlantClock,
    ) -> Result<Hil, HilError> {
        if !qemu_available() {
            return Err(HilError::NoQemu);
        }
        let mut plant = Plant::new(&robot.geometry, &robot.can, start)
            .map_err(|e| HilError::Io(format!("the start legs have no IK solution: {e:?}")))?;
        plant.set_clock(clock);
        let (obs_listener, obs_port) = listener()?;
        let (can_listener, can_port) = listener()?;
        let (monitor_listener, monitor_port) = listener()?;
        let scratch =
            std::env::temp_dir().join(format!("wheelleg-hil-{}-{obs_port}", std::process::id()));
        std::fs::create_dir_all(&scratch).map_err(io("creating the scratch folder"))?;
        // QEMU runs a copy, so that the layout read here is the image that runs even when the
        // image is rebuilt meanwhile (a long run over many scenes starts QEMU once per scene).
        let copy = scratch.join("image.elf");
        std::fs::copy(image, &copy)
            .map_err(|e| HilError::Io(format!("copying {}: {e}", image.display())))?;
        let image = copy.as_path();
        let layout = RamLayout::of_image(image)?;
        let paint = layout.write_paint(&scratch)?;
        // UART 0 is the console (unused), UART 1 the observation link, UART 2 the CAN
        // adapter; Nagle's algorithm off on both, since QEMU writes a byte per segment and a
        // delayed acknowledgement would hold the next one back. Instructions are counted
        // (1 ns each) and idle time is skipped, so that the firmware's SysTick periods cost
        // only what the firmware executes. The loader paints the free RAM before the core
        // starts, and the monitor saves it at the end ([`Hil::ram_use`]).
        //
        // The firmware's clock runs while it polls for the host's bytes, so a host starved of
        // the CPU looks to it like a dead adapter (its link timeout is 5 periods, some 50 M
        // instructions of polling). QEMU therefore runs at a lower priority than the host
        // (`nice`, where the machine has it): the host's threads preempt it when their bytes
        // are due.
        // On the emulated clock the adapter's bytes reach the firmware through a FIFO it reads
        // by semihosting (docs/controller.md, "The emulated clock"): made here, opened here
        // for reading and writing so that neither end's open waits for the other.
        let fifo = match clock {
            PlantClock::Lockstep => None,
            PlantClock::Emulated => Some(make_fifo(&scratch.join(ADAPTER_FIFO))?),
        };
        let mut qemu = qemu_command()
            .args(["-machine", "mps2-an386", "-display", "none"])
            .args([
                "-monitor",
                &format!("tcp:127.0.0.1:{monitor_port},nodelay=on"),
            ])
            .args(["-serial", "null"])
            .args(["-serial", &format!("tcp:127.0.0.1:{obs_port},nodelay=on")])
            .args(["-serial", &format!("tcp:127.0.0.1:{can_port},nodelay=on")])
            .arg("-device")
            .arg(format!(
                "loader,file={},addr={:#x},force-raw=on",
                paint.display(),
                layout.stack_limit
            ))
            .args(semihosting(clock))
            .args(["-icount", icount(clock), "-kernel"])
            .arg(image)
            .current_dir(&scratch)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::NotFound => HilError::NoQemu,
                _ => io("starting QEMU")(e),
            })?;
        let monitor = accept(&monitor_listener, &mut qemu, "monitor")?;
        let obs = accept(&obs_listener, &mut qemu, "observation link (UART 1)")?;
        let can = accept(&can_listener, &mut qemu, "CAN adapter link (UART 2)")?;
        let plant = Arc::new(Mutex::new(plant));
        let shared = Arc::clone(&plant);
        let can = std::thread::spawn(move || serve_can(can, fifo, shared));
        let window = CollisionGuard::new(robot, DEFAULT_MARGIN_M)
            .fine_window(MapGrid::GUARD_FINE.side, MapGrid::GUARD_FINE.cell_m);
        let mut hil = Hil {
            qemu,
            obs,
            monitor,
            layout,
            scratch,
            received: Vec::new(),
            plant,
            can: Some(can),
            window,
            fine: vec![0.0; MapGrid::GUARD_FINE.cells()],
            sim_observation: SimObservation::default(),
            clock,
            robot: *robot,
        };
        // The monitor's greeting ends in its first prompt.
        hil.monitor_prompt()?;
        Ok(hil)
    }
}

/// The FIFO of the emulated clock's adapter bytes, in QEMU's working folder (the firmware's
/// `Emulated::FIFO`).
const ADAPTER_FIFO: &str = "adapter.fifo";

/// Makes the FIFO at `path` and opens it for reading and writing (Linux opens a FIFO so
/// without waiting for a reader; the host only writes).
fn make_fifo(path: &Path) -> Result<std::fs::File, HilError> {
    let made = std::process::Command::new("mkfifo")
        .arg(path)
        .status()
        .map_err(io("running mkfifo"))?;
    if !made.success() {
        return Err(HilError::Io(format!("mkfifo {} failed", path.display())));
    }
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .map_err(io("opening the adapter's FIFO"))
}

/// QEMU's semihosting for `clock`: the emulated clock's image reads its adapter's bytes by it.
fn semihosting(clock: PlantClock) -> &'static [&'static str] {
    match clock {
        PlantClock::Lockstep => &[],
        PlantClock::Emulated => &["-semihosting-config", "enable=on,target=native"],
    }
}

/// The adapter's side of the CAN UART: the firmware's lines to the plant, its answers back
/// (into the `fifo` on the emulated clock).
fn serve_can(
    mut stream: TcpStream,
    mut fifo: Option<std::fs::File>,
    plant: Arc<Mutex<Plant>>,
) -> Result<(), String> {
    let mut buf = [0u8; 4096];
    loop {
        let n = match stream.read(&mut buf) {
            Ok(0) => return Ok(()),
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            // QEMU killed at the end.
            Err(_) => return Ok(()),
        };
        let out = plant
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .feed(&buf[..n])
            .map_err(|e| format!("the CAN adapter: {e}"))?;
        let written = match fifo.as_mut() {
            Some(fifo) => fifo.write_all(&out),
            None => stream.write_all(&out),
        };
        if !out.is_empty() && written.is_err() {
            return Ok(());
        }
    }
}
