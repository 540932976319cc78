//! `baton_proto::testing::fuzz::scenario_file` under libFuzzer.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| baton_proto::testing::fuzz::scenario_file(data));
