//! The trainer's checkpoint reader (trainer/src/checkpoint.rs) on raw file bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| wheelleg_fuzz::check_checkpoint_file(data));
