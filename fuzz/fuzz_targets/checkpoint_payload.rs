//! The trainer's checkpoint reader past the header checksum (the postcard payload).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| wheelleg_fuzz::check_checkpoint_payload(data));
