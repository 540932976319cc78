//! The fuzz targets (`fuzz/`, `baton_proto::testing::fuzz`, `baton_ros2::cdr::fuzz_decode`) on every seed they start from and on every input a
//! fuzzer once made them fail on (`fuzz/regressions/TARGET/`): what a fuzzer found stays found. The wire and
//! journal seeds are messages and records a simulated cell really sent and journaled, the cdr seeds messages of
//! the built-in ROS 2 types; they must still decode, or
//! the fuzzer would start from noise (write them again with `BATON_FUZZ_SEEDS=write`).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

use baton_proto::cluster::journal;
use baton_proto::testing::fuzz::{self, TARGETS};
use baton_proto::testing::simulated_cluster::{Faults, SimCluster};
use baton_ros2::cdr::{self, FUZZ_TYPES};
use baton_ros2::interfaces::{Distro, Interfaces};
use baton_tests::harness::not_checked;
use baton_tests::loopback::repo;
use baton_tests::shared_dir;

/// Files under `dir` (recursively) whose names end with one of `suffixes` (all files for none).
fn files(dir: &Path, suffixes: &[&str]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else { return out };
    for e in entries.flatten() {
        let path = e.path();
        if path.is_dir() {
            out.extend(files(&path, suffixes));
        } else if suffixes.is_empty() || suffixes.iter().any(|s| path.to_string_lossy().ends_with(s)) {
            out.push(path);
        }
    }
    out.sort();
    out
}

/// Where each target's seeds come from: its own folder under `fuzz/seeds/`, and for charts and scenarios the
/// project's examples and tests and the public corpus (`fuzz/run` gathers the same).
fn seeds(target: &str) -> Vec<PathBuf> {
    let mut all = files(&repo(&format!("fuzz/seeds/{target}")), &[]);
    match target {
        "chart" => {
            all.extend(files(&repo("examples"), &[".st"]));
            all.extend(files(&repo("tests/charts"), &[]));
            let corpus = shared_dir().join("corpus/sfc");
            if corpus.is_dir() {
                all.extend(files(&corpus, &[".st", ".xml"]));
            } else {
                not_checked(&format!("the public SFC corpus is not at {}", corpus.display()));
            }
        }
        "scenario" => {
            all.extend(files(&repo("examples"), &[".test.toml"]));
            all.extend(files(&repo("tests/baton_test"), &[".test.toml"]));
        }
        _ => {}
    }
    all
}

/// A target's body, whichever crate holds it.
type Body<'a> = dyn Fn(&[u8]) + 'a;

/// The built-in ROS 2 interface library, as the `cdr` target loads it.
fn ros2_library() -> Interfaces {
    Interfaces::load(Distro::Jazzy, &[]).expect("the built-in interfaces")
}

#[test]
fn every_seed_and_every_input_a_fuzzer_failed_on_passes_its_target() {
    let lib = ros2_library();
    let cdr = |data: &[u8]| baton_ros2::cdr::fuzz_decode(&lib, data);
    let mut targets: Vec<(&str, &Body<'_>)> = TARGETS.iter().map(|(n, f)| (*n, f as &Body<'_>)).collect();
    targets.push(("cdr", &cdr));
    let mut failed = Vec::new();
    for (target, body) in targets {
        let inputs: Vec<PathBuf> =
            seeds(target).into_iter().chain(files(&repo(&format!("fuzz/regressions/{target}")), &[])).collect();
        assert!(!inputs.is_empty(), "target `{target}` has no seed");
        for path in inputs {
            let bytes = std::fs::read(&path).expect("read an input");
            if catch_unwind(AssertUnwindSafe(|| body(&bytes))).is_err() {
                failed.push(format!("{target}: {}", path.display()));
            }
        }
    }
    assert!(failed.is_empty(), "inputs that fail their target:\n{}", failed.join("\n"));
}

/// A cell of two robots making three parts, a robot's link dropping and duplicating messages, every message and
/// journal record kept.
fn simulated_cell() -> SimCluster {
    let source = std::fs::read_to_string(repo("examples/cell.st")).expect("the example chart");
    let faults = Faults { duplicate: 0.1, reorder: true, delay_ms_max: 20, loss: 0.1 };
    let mut cell = SimCluster::new(&source, &[("robot1", &["assembler"]), ("robot2", &[])], faults, 7);
    cell.captured = Some(Vec::new());
    cell.set_at(0, "parts", serde_json::json!(3));
    assert!(cell.run(120_000), "the simulated cell did not finish: {:?}", cell.errors);
    cell
}

/// Up to `n` of `items`, spread over all of them.
fn spread<T: Clone>(items: &[T], n: usize) -> Vec<T> {
    let step = items.len().div_ceil(n).max(1);
    items.iter().step_by(step).cloned().collect()
}

/// Each type of the `cdr` target, its default and (for those that have them) a value with strings and sequences
/// filled in, encoded as a peer would send them.
fn write_cdr_seeds() {
    let dir = repo("fuzz/seeds/cdr");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("make the seed folder");
    let lib = ros2_library();
    let filled: &[(&str, &str)] = &[
        ("std_msgs/msg/String", "(data := 'gripper closed')"),
        ("sensor_msgs/msg/JointState", "(name := ['a', 'b'], position := [0.5, 1.5], velocity := [0.0])"),
        ("nav_msgs/msg/Path", "(header := (frame_id := 'map'), poses := [(pose := (position := (x := 1.0)))])"),
    ];
    for (i, name) in FUZZ_TYPES.iter().enumerate() {
        let def = lib.msg(name).expect("a built-in type");
        let mut values = vec![cdr::encode(&lib, &def, None).expect("the default encodes")];
        for (_, text) in filled.iter().filter(|(n, _)| n == name) {
            let lit = baton_proto::front::literal::parse(text).expect("a literal");
            values.push(cdr::encode(&lib, &def, Some(&lit)).expect("the value encodes"));
        }
        for (k, bytes) in values.into_iter().enumerate() {
            let mut seed = vec![i as u8];
            seed.extend(bytes);
            std::fs::write(dir.join(format!("{i:02}-{k}")), seed).expect("write a seed");
        }
    }
}

#[test]
fn the_wire_and_journal_seeds_still_decode() {
    let wire_dir = repo("fuzz/seeds/wire");
    let journal_dir = repo("fuzz/seeds/journal");
    if std::env::var("BATON_FUZZ_SEEDS").as_deref() == Ok("write") {
        let cell = simulated_cell();
        for dir in [&wire_dir, &journal_dir] {
            let _ = std::fs::remove_dir_all(dir);
            std::fs::create_dir_all(dir).expect("make the seed folder");
        }
        let captured = cell.captured.clone().unwrap_or_default();
        for kind in 0..3u8 {
            let of_kind: Vec<Vec<u8>> = captured.iter().filter(|(k, _)| *k == kind).map(|(_, b)| b.clone()).collect();
            for (i, bytes) in spread(&of_kind, 12).into_iter().enumerate() {
                let mut seed = vec![kind];
                seed.extend(bytes);
                std::fs::write(wire_dir.join(format!("{kind}-{i:02}")), seed).expect("write a seed");
            }
        }
        for (i, record) in spread(&cell.journal, 40).into_iter().enumerate() {
            std::fs::write(journal_dir.join(format!("{i:02}")), record).expect("write a seed");
        }
        write_cdr_seeds();
    }
    let wire_seeds = files(&wire_dir, &[]);
    let journal_seeds = files(&journal_dir, &[]);
    assert!(
        wire_seeds.len() >= 30 && journal_seeds.len() >= 20,
        "too few seeds: write them with BATON_FUZZ_SEEDS=write"
    );
    for path in wire_seeds {
        let bytes = std::fs::read(&path).expect("read a seed");
        let decoded = match bytes.split_first() {
            Some((&kind, m)) if kind < 3 => fuzz::decode_message(kind, m),
            _ => panic!("{}: not a wire seed", path.display()),
        };
        assert!(decoded.is_ok(), "{} no longer decodes ({decoded:?}): write the seeds again", path.display());
    }
    let lib = ros2_library();
    let cdr_seeds = files(&repo("fuzz/seeds/cdr"), &[]);
    assert!(cdr_seeds.len() > FUZZ_TYPES.len(), "too few seeds: write them with BATON_FUZZ_SEEDS=write");
    for path in cdr_seeds {
        let bytes = std::fs::read(&path).expect("read a seed");
        let (&pick, message) = bytes.split_first().expect("a seed");
        let def = lib.msg(FUZZ_TYPES[pick as usize % FUZZ_TYPES.len()]).expect("a built-in type");
        let decoded = cdr::decode(&lib, &def, message).map(drop);
        assert!(decoded.is_ok(), "{} no longer decodes ({decoded:?}): write the seeds again", path.display());
    }
    for path in journal_seeds {
        let bytes = std::fs::read(&path).expect("read a seed");
        let entry = journal::decode(&bytes);
        assert!(entry.is_ok(), "{} no longer decodes ({entry:?}): write the seeds again", path.display());
    }
}
