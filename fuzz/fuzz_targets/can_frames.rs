//! The runtime's CAN codec and feedback tracker, and the simulated axes, on arbitrary frames.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| wheelleg_fuzz::check_can_frames(data));
