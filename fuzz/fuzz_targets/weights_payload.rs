//! The runtime's weights loader past the envelope checksum (the layer records).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| wheelleg_fuzz::check_weights_payload(data));
