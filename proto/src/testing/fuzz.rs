//! The bodies of the fuzz targets (`fuzz/`, cargo-fuzz): what Baton does with bytes from outside — a peer's
//! message, a journal's record, a chart file, a scenario file. Each takes any bytes and must neither panic nor
//! hang; the fuzzer calls them with what it makes, and `tests/tests/fuzz_regressions.rs` calls them with every
//! seed and every input a fuzzer once crashed on (`fuzz/regressions/TARGET/`).

use std::path::Path;

use crate::cluster::journal;
use crate::cluster::wire::{
    self, AgentInfo, ChartSource, CtlRequest, DeviceReport, Report, SetRequest, StatusReport, ToAgent, VarUpdate,
    WhyReport,
};
use crate::front::source;
use crate::pipeline;
use crate::testing::scenario;

/// A target's body: any bytes in.
pub type Target = fn(&[u8]);

/// The targets, by name, as `fuzz/Cargo.toml` names its binaries.
pub const TARGETS: &[(&str, Target)] =
    &[("wire", wire_message), ("journal", journal_record), ("chart", chart_file), ("scenario", scenario_file)];

/// Every message a Baton process decodes from a peer: the first byte picks the type, the rest is the message.
pub fn wire_message(data: &[u8]) {
    if let Some((&kind, bytes)) = data.split_first() {
        let _ = decode_message(kind, bytes);
    }
}

/// `bytes` decoded as the message type `kind` picks (modulo 10): 0 to an agent, 1 a report, 2 a variable update,
/// 3 a device report, 4 an agent's info, 5 `set`, 6 `ctl`, 7 a status, 8 a why report, 9 a chart's source.
pub fn decode_message(kind: u8, bytes: &[u8]) -> Result<(), wire::WireError> {
    match kind % 10 {
        0 => wire::decode::<ToAgent>(bytes).map(drop),
        1 => wire::decode::<Report>(bytes).map(drop),
        2 => wire::decode::<VarUpdate>(bytes).map(drop),
        3 => wire::decode::<DeviceReport>(bytes).map(drop),
        4 => wire::decode::<AgentInfo>(bytes).map(drop),
        5 => wire::decode::<SetRequest>(bytes).map(drop),
        6 => wire::decode::<CtlRequest>(bytes).map(drop),
        7 => wire::decode::<StatusReport>(bytes).map(drop),
        8 => wire::decode::<WhyReport>(bytes).map(drop),
        _ => wire::decode_with_limit::<ChartSource>(bytes, crate::limits::CHART_SOURCE_BYTES_MAX).map(drop),
    }
}

/// A journal's record as read back on resume or replay: it decodes or says why, and what decodes, encoded
/// again, decodes to the same entry (a resume rebuilds what was written).
pub fn journal_record(data: &[u8]) {
    if let Ok(entry) = journal::decode(data) {
        let again = journal::encode(&entry);
        assert_eq!(journal::decode(&again), Ok(entry), "a record re-encoded decodes to another");
    }
}

/// A chart file as `baton check` reads it: bytes in any encoding Baton accepts, text SFC or PLCopen TC6 XML.
pub fn chart_file(data: &[u8]) {
    if source::check_size(data.len() as u64).is_err() {
        return;
    }
    if let Ok(decoded) = source::decode(data) {
        let _ = pipeline::check_source(&decoded.text);
    }
}

/// The chart a fuzzed scenario names, whatever its name.
const SCENARIO_CHART: &str = "PROGRAM p\nVAR x : BOOL; n : INT; END_VAR\nINITIAL_STEP S: END_STEP\n\
    STEP T: {agent := 'r1'} Move(N, x); END_STEP\nTRANSITION FROM S TO T := n > 0; END_TRANSITION\n\
    TRANSITION FROM T TO S := x; END_TRANSITION\nACTION Move: {skill := 'motion', ms := 100} END_ACTION\nEND_PROGRAM\n";

/// A `baton test` scenario file, its chart a fixed one of two steps.
pub fn scenario_file(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let read = |_: &Path| Ok(SCENARIO_CHART.to_string());
    let _ = scenario::parse(Path::new("fuzz.test.toml"), text, &read);
}
