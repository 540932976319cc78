//! `baton_proto::testing::fuzz::wire_message` under libFuzzer.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| baton_proto::testing::fuzz::wire_message(data));
