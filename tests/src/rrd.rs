//! Reading a recording (.rrd) back with the Rerun SDK of Baton's version, for the tests that check what a run
//! put on its timeline.

use std::path::Path;

use crate::loopback::repo;

/// Whether `python3` has rerun-sdk 0.36.3; in CI (`CI` set) its absence fails the test.
pub fn reader_available() -> bool {
    let probe = std::process::Command::new("python3")
        .args(["-c", "import rerun, sys; sys.exit(0 if rerun.__version__ == '0.36.3' else 1)"])
        .output();
    let ok = probe.is_ok_and(|o| o.status.success());
    if !ok {
        crate::missing(
            "reading a recording back needs python3 with rerun-sdk 0.36.3: \
             pip install 'rerun-sdk[datafusion]==0.36.3' (as .ci/run does)",
        );
    }
    ok
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
