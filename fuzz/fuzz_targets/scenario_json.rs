//! The scenario file reader (sim/src/scenario_file.rs) on arbitrary text.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| wheelleg_fuzz::check_scenario_json(data));
