//! Puts memory.x and device.x where cortex-m-rt's link.x finds them (this package's build
//! output comes first on the linker's search path, before the controller's QEMU scripts;
//! scripts/board.sh checks the image was linked for the part), and the policy's weights file
//! where the image includes it: `weights/policy.wlw`, or the file `WHEELLEG_WEIGHTS` names (a
//! path relative to the workspace root, or absolute), as controller/build.rs does, so that a
//! board carries the weights, and so the robot, it is built for. Rebuilds when any changes.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").unwrap_or_default());
    for script in ["memory.x", "device.x"] {
        if let Err(error) = fs::copy(script, out.join(script)) {
            println!("cargo::error={script}: {error}");
        }
        println!("cargo::rerun-if-changed={script}");
    }
    println!("cargo::rustc-link-search={}", out.display());
    println!("cargo::rerun-if-env-changed=WHEELLEG_WEIGHTS");
    let weights = match env::var_os("WHEELLEG_WEIGHTS") {
        Some(path) => PathBuf::from("..").join(path),
        None => PathBuf::from("../weights/policy.wlw"),
    };
    println!("cargo::rerun-if-changed={}", weights.display());
    if let Err(error) = fs::copy(&weights, out.join("policy.wlw")) {
        println!("cargo::error={}: {error}", weights.display());
    }
}
