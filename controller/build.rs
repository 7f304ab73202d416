//! Puts memory.x and device.x where cortex-m-rt's link.x finds it, and the policy's weights file
//! where the images include it: `weights/policy.wlw`, or the file `WHEELLEG_WEIGHTS` names (a
//! path relative to the workspace root, or absolute), so that an image carries the weights, and
//! so the robot, it is built for. Rebuilds when any of them changes.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").unwrap_or_default());
    for script in ["memory.x", "device.x"] {
        if let Err(error) = fs::copy(script, out.join(script)) {
            println!("cargo::error={script}: {error}");
        }
    }
    println!("cargo::rustc-link-search={}", out.display());
    println!("cargo::rerun-if-changed=memory.x");
    println!("cargo::rerun-if-changed=device.x");
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
