//! `baton_ros2::cdr::fuzz_decode` under libFuzzer, on the built-in interface library.
#![no_main]

use std::sync::OnceLock;

use baton_ros2::interfaces::{Distro, Interfaces};

static LIBRARY: OnceLock<Interfaces> = OnceLock::new();

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let lib = LIBRARY.get_or_init(|| Interfaces::load(Distro::Jazzy, &[]).expect("the built-in interfaces"));
    baton_ros2::cdr::fuzz_decode(lib, data);
});
