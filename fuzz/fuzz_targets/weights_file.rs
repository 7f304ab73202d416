//! The runtime's weights loader on raw file bytes (runtime/src/model/load/).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| wheelleg_fuzz::check_weights_file(data));
