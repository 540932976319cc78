//! `baton_proto::testing::fuzz::journal_record` under libFuzzer.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| baton_proto::testing::fuzz::journal_record(data));
