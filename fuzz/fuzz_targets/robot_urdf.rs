//! The URDF importer (robot/src/urdf.rs) on arbitrary text.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| wheelleg_fuzz::check_robot_urdf(data));
