//! The SLCAN line decoder and the simulated adapter in front of the axes, on arbitrary bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| wheelleg_fuzz::check_slcan_lines(data));
