//! The trainer's trajectory batch reader (trainer/src/trajectory/batch_file.rs), CRCs fixed up.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| wheelleg_fuzz::check_trajectory_batch(data));
