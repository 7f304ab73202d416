//! Puts memory.x and device.x where cortex-m-rt's link.x finds it, and rebuilds when it or the weights change.
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
    println!("cargo::rerun-if-changed=../weights/policy.wlw");
}
