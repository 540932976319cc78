//! `baton_proto::testing::fuzz::chart_file` under libFuzzer.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| baton_proto::testing::fuzz::chart_file(data));
