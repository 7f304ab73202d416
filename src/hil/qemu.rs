//! The firmware's production image and the QEMU process that runs it: where the image is,
//! how it is built when missing, and how QEMU is started below the host's priority.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use super::plant::PlantClock;
use super::HilError;

/// The production image, where `cargo +nightly build --release` in `controller/` puts it.
pub fn default_image() -> PathBuf {
    image_for(PlantClock::Lockstep)
}

/// The production image for `clock`: the emulated clock's is built with the `emulated-clock`
/// feature into its own target folder ([`build_command`]).
pub fn image_for(clock: PlantClock) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("controller")
        .join(target_for(clock))
        .join("thumbv7em-none-eabihf/release/wheelleg-controller")
}

/// The emulated clock's image's target folder, under `controller/`.
const EMULATED_TARGET: &str = "target/emulated-clock";

/// The command that builds the production image.
pub const BUILD_COMMAND: &str =
    "cd controller && cargo +nightly build --release --bin wheelleg-controller";

/// The arguments of `cargo +nightly` in `controller/` that build the image for `clock` into
/// the target folder `target` (under `controller/`).
pub fn build_command(clock: PlantClock, target: &str) -> Vec<String> {
    let mut args = vec!["build", "--release", "--bin", "wheelleg-controller"];
    if clock == PlantClock::Emulated {
        args.extend(["--features", "emulated-clock"]);
    }
    args.extend(["--target-dir", target]);
    args.into_iter().map(String::from).collect()
}

/// The default image's target folder for `clock`, under `controller/`.
fn target_for(clock: PlantClock) -> &'static str {
    match clock {
        PlantClock::Lockstep => "target",
        PlantClock::Emulated => EMULATED_TARGET,
    }
}

/// How much lower than the host's QEMU's scheduling priority is (`nice` increment).
const QEMU_NICE_INCREMENT: &str = "5";

/// `qemu-system-arm`, under `nice` when the machine has it (see [`Hil::start`]; asked once
/// per process, not per episode).
pub(super) fn qemu_command() -> Command {
    static HAS_NICE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let has_nice = *HAS_NICE.get_or_init(|| {
        Command::new("nice")
            .arg("true")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    });
    if has_nice {
        let mut command = Command::new("nice");
        command.args(["-n", QEMU_NICE_INCREMENT, "qemu-system-arm"]);
        command
    } else {
        Command::new("qemu-system-arm")
    }
}

/// The production image for `clock` with the weights file at `weights` built into it
/// (`WHEELLEG_WEIGHTS`, controller/build.rs), in a target folder of its own named by the
/// file's contents, so that each weights file keeps its build.
pub fn image_with_weights(weights: &Path, clock: PlantClock) -> Result<PathBuf, HilError> {
    use std::hash::{Hash, Hasher};
    let bytes = std::fs::read(weights)
        .map_err(|e| HilError::NoImage(weights.to_path_buf(), format!("cannot read: {e}")))?;
    let weights = weights
        .canonicalize()
        .map_err(|e| HilError::NoImage(weights.to_path_buf(), e.to_string()))?;
    // std's hasher with its fixed keys: the same file names the same folder on this machine.
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    bytes.hash(&mut hasher);
    let clock_dir = match clock {
        PlantClock::Lockstep => "lockstep",
        PlantClock::Emulated => "emulated-clock",
    };
    let target = format!("target/weights-{:016x}/{clock_dir}", hasher.finish());
    let controller = Path::new(env!("CARGO_MANIFEST_DIR")).join("controller");
    let image = controller
        .join(&target)
        .join("thumbv7em-none-eabihf/release/wheelleg-controller");
    // Built every time: cargo rebuilds only what changed, so a firmware changed since the
    // last run is never run stale (a second or so when nothing did).
    let mut command = Command::new("cargo");
    command
        .arg("+nightly")
        .args(build_command(clock, &target))
        .env("WHEELLEG_WEIGHTS", &weights);
    build(command, image)
}

/// Runs the image's build `command` (`cargo +nightly build ...`) in `controller/`; `image` once
/// it is there.
fn build(mut command: Command, image: PathBuf) -> Result<PathBuf, HilError> {
    let controller = Path::new(env!("CARGO_MANIFEST_DIR")).join("controller");
    let built = command
        .current_dir(&controller)
        .stdout(Stdio::null())
        .status();
    match built {
        Ok(status) if status.success() && image.is_file() => Ok(image),
        Ok(status) => Err(HilError::NoImage(
            image,
            format!("the build failed: {status}"),
        )),
        Err(e) => Err(HilError::NoImage(image, format!("cargo cannot run: {e}"))),
    }
}

/// Whether `qemu-system-arm` runs here.
pub fn qemu_available() -> bool {
    Command::new("qemu-system-arm")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// The firmware image at `path`, or the default one for `clock`, built first when missing.
pub fn find_or_build_image(path: Option<&Path>, clock: PlantClock) -> Result<PathBuf, HilError> {
    let image = path.map_or_else(|| image_for(clock), Path::to_path_buf);
    if image.is_file() {
        return Ok(image);
    }
    if path.is_some() {
        return Err(HilError::NoImage(image, "no such file".into()));
    }
    let mut command = Command::new("cargo");
    command
        .arg("+nightly")
        .args(build_command(clock, target_for(clock)));
    build(command, image)
}
