//! Reading a recording (.rrd) back with the Rerun SDK of Baton's version, for the tests that check what a run
//! put on its timeline.

use std::path::Path;

use crate::loopback::repo;

/// Why a recording cannot be read back here.
pub const NO_READER: &str = "reading a recording back needs python3 with rerun-sdk 0.36.3: \
                             pip install 'rerun-sdk[datafusion]==0.36.3' (as .ci/run does)";

/// Whether `python3` has rerun-sdk 0.36.3, to read recordings back.
pub fn has_reader() -> bool {
    let probe = std::process::Command::new("python3")
        .args(["-c", "import rerun, sys; sys.exit(0 if rerun.__version__ == '0.36.3' else 1)"])
        .output();
    probe.is_ok_and(|o| o.status.success())
}

/// A test that reads a recording back needs the reader: without it the test is ignored (in CI it fails).
pub fn require_reader() {
    if !has_reader() {
        crate::missing(NO_READER);
    }
}

pub fn read_recording(rrd: &Path) -> serde_json::Value {
    let script = repo("tests/scripts/read_recording.py");
    let out = std::process::Command::new("python3").arg(&script).arg(rrd).output().expect("python3 runs");
    assert!(out.status.success(), "reading {} failed: {}", rrd.display(), String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("the reader prints JSON")
}

/// The recording's log view: (level, text) in the order logged.
pub fn log_lines(recording: &serde_json::Value) -> Vec<(String, String)> {
    recording["log"]
        .as_array()
        .expect("log")
        .iter()
        .map(|e| (e[1].as_str().unwrap_or_default().to_string(), e[2].as_str().unwrap_or_default().to_string()))
        .collect()
}
