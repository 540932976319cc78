//! The `baton` binary as a user runs it: exit codes, output formats, and bad input.

use std::path::PathBuf;
use std::process::{Command, Output};

fn baton(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_baton")).args(args).output().expect("baton runs")
}

fn repo(path: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join(path).to_string_lossy().into_owned()
}

fn temp_file(name: &str, text: &str) -> String {
    let dir = std::env::temp_dir().join(format!("baton-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join(name);
    std::fs::write(&path, text).expect("temp file");
    path.to_string_lossy().into_owned()
}

#[test]
fn check_exit_codes() {
    let valid = baton(&["check", &repo("examples/tank.st")]);
    assert_eq!(valid.status.code(), Some(0), "{}", String::from_utf8_lossy(&valid.stderr));
    assert!(String::from_utf8_lossy(&valid.stdout).contains("chart `Tank` is valid"));

    let invalid = baton(&["check", &repo("tests/conformance/diagnostics/names.st")]);
    assert_eq!(invalid.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&invalid.stderr);
    assert!(stderr.contains("names.st:13:25: error: unknown step `Nowhere`"), "{stderr}");
    assert!(stderr.contains("^^^^^^^"), "offending text is underlined: {stderr}");

    let warned = baton(&["check", &repo("tests/conformance/diagnostics/warnings_only.st")]);
    assert_eq!(warned.status.code(), Some(0), "warnings keep exit 0");
    assert!(String::from_utf8_lossy(&warned.stderr).contains("warning:"));

    assert_eq!(baton(&["check", "/nonexistent/chart.st"]).status.code(), Some(2));
    assert_eq!(baton(&["check"]).status.code(), Some(2));
}

#[test]
fn sim_prints_json_lines_in_cycle_order() {
    let out = baton(&[
        "sim",
        &repo("examples/tank.st"),
        "--inputs",
        &repo("examples/tank.inputs.jsonl"),
        "--cycle-ms",
        "10",
        "--until-ms",
        "160",
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("each line is JSON"))
        .collect();
    assert_eq!(lines[0], serde_json::json!({"t_ms": 0, "event": "activate", "name": "Idle"}));
    assert!(lines.contains(&serde_json::json!({"t_ms": 50, "event": "fire", "name": "Start"})));
    let times: Vec<u64> = lines.iter().map(|l| l["t_ms"].as_u64().expect("t_ms")).collect();
    assert!(times.windows(2).all(|w| w[0] <= w[1]), "events come in time order");
    assert!(times.iter().all(|&t| t <= 160), "no cycle after --until-ms");
}

#[test]
fn sim_rejects_a_malformed_input_file_with_exit_2() {
    let chart = repo("examples/tank.st");
    for (name, text, expect) in [
        ("garbage.jsonl", "{\"t_ms\": 10, \"set\": {\"start\": true}}\nnot json\n", "line 2"),
        ("unknown.jsonl", "{\"t_ms\": 10, \"set\": {\"stop\": true}}\n", "unknown variable `stop`"),
        ("type.jsonl", "{\"t_ms\": 10, \"set\": {\"level\": 1.5}}\n", "`level` is INT"),
        ("negative.jsonl", "{\"t_ms\": -1, \"set\": {}}\n", "line 1"),
    ] {
        let inputs = temp_file(name, text);
        let out = baton(&["sim", &chart, "--inputs", &inputs]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name}: {stderr}");
        assert!(stderr.contains(expect), "{name}: {stderr}");
        assert!(out.stdout.is_empty(), "{name}: nothing runs on bad input");
    }
}

#[test]
fn sim_refuses_an_invalid_chart_with_exit_1() {
    let out = baton(&["sim", &repo("tests/conformance/diagnostics/unsafe_exit_from_parallel.st")]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("unsafe chart"));
    assert!(out.stdout.is_empty());
}

#[test]
fn sim_needs_pou_when_a_file_holds_several_charts() {
    let two = temp_file(
        "two.st",
        "PROGRAM A INITIAL_STEP S: END_STEP END_PROGRAM\nPROGRAM B INITIAL_STEP S: END_STEP END_PROGRAM\n",
    );
    let out = baton(&["sim", &two]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--pou"));
    let out = baton(&["sim", &two, "--pou", "b", "--until-ms", "0"]);
    assert_eq!(out.status.code(), Some(0));
    assert_eq!(String::from_utf8_lossy(&out.stdout), "{\"t_ms\":0,\"event\":\"activate\",\"name\":\"S\"}\n");
}

#[test]
fn a_byte_order_mark_and_crlf_line_ends_are_accepted() {
    let text = std::fs::read_to_string(repo("examples/tank.st")).expect("tank.st").replace('\n', "\r\n");
    let path = temp_file("bom_crlf.st", &format!("\u{feff}{text}"));
    let out = baton(&["check", &path]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    // And positions are still those of the file: line 1, column 1 is after the mark.
    let broken = temp_file("bom_broken.st", "\u{feff}INITIAL_STEP S0 END_STEP\r\n");
    let out = baton(&["check", &broken]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("bom_broken.st:1:17: error: expected `:`"), "{stderr}");
}

#[test]
fn a_reader_that_goes_away_ends_the_output_quietly() {
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    // `baton sim … | head -1`: the reader closes the pipe after one line.
    let mut child = Command::new(env!("CARGO_BIN_EXE_baton"))
        .args(["sim", &repo("examples/tank.st"), "--until-ms", "100000000"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("baton sim runs");
    let mut first = String::new();
    BufReader::new(child.stdout.take().expect("stdout")).read_line(&mut first).expect("a line");
    let out = child.wait_with_output().expect("baton sim ends");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!first.is_empty());
    assert!(!stderr.contains("panicked") && !stderr.contains("failed printing"), "{stderr}");
    assert_ne!(out.status.code(), Some(101), "{stderr}");
}

#[test]
fn check_json_lists_the_charts_and_every_diagnostic() {
    let out = baton(&["check", "--json", &repo("tests/conformance/diagnostics/names.st")]);
    assert_eq!(out.status.code(), Some(1), "the exit status of baton check");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    let d = v["diagnostics"].as_array().expect("diagnostics");
    let nowhere = d.iter().find(|d| d["message"] == "unknown step `Nowhere`").expect("the unknown step");
    assert_eq!(
        (nowhere["severity"].as_str(), nowhere["line"].as_u64(), nowhere["col"].as_u64()),
        (Some("error"), Some(13), Some(25))
    );
    assert!(nowhere["file"].as_str().unwrap_or_default().ends_with("names.st"));

    let out = baton(&["check", "--json", &repo("examples/tank.st")]);
    assert_eq!(out.status.code(), Some(0));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    let chart = &v["charts"][0];
    assert_eq!(chart["pou"], "Tank");
    assert!(chart["initial_steps"].as_array().is_some_and(|s| s.len() == 1));
    let start = &chart["transitions"][0];
    assert_eq!(
        (start["name"].as_str(), &start["from"], &start["to"]),
        (Some("Start"), &serde_json::json!(["Idle"]), &serde_json::json!(["Fill"]))
    );
    assert_eq!(v["diagnostics"].as_array().map(Vec::len), Some(0));
}

#[test]
fn export_writes_plcopen_that_baton_reads_back_and_refuses_an_invalid_chart() {
    let out = baton(&["export", "--plcopen", &repo("examples/cell.st")]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let xml = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(xml.contains("xmlns=\"http://www.plcopen.org/xml/tc6_0201\"") && xml.contains("<step "), "{xml}");
    // The header's creation time is today's, as xsd:dateTime.
    let created = xml.split("creationDateTime=\"").nth(1).and_then(|r| r.get(..19)).expect("a creation time");
    assert!(created.starts_with("20") && created.as_bytes()[10] == b'T', "{created}");
    let file = temp_file("cell_export.xml", &xml);
    let back = baton(&["check", &file]);
    assert_eq!(back.status.code(), Some(0), "{}", String::from_utf8_lossy(&back.stderr));
    assert!(String::from_utf8_lossy(&back.stdout).contains("chart `cell` is valid: 10 steps, 10 transitions"));
    // -o writes the file instead.
    let target = temp_file("cell_o.xml", "");
    let written = baton(&["export", "--plcopen", &repo("examples/cell.st"), "-o", &target]);
    assert_eq!(written.status.code(), Some(0));
    assert!(std::fs::read_to_string(&target).expect("written").contains("<pou name=\"cell\""));

    let invalid = baton(&["export", "--plcopen", &repo("tests/conformance/diagnostics/names.st")]);
    assert_eq!(invalid.status.code(), Some(1));
    assert!(invalid.stdout.is_empty(), "nothing is exported from a chart with errors");
    assert!(String::from_utf8_lossy(&invalid.stderr).contains("nothing was exported"));
}

fn temp_bytes(name: &str, bytes: &[u8]) -> String {
    let dir = std::env::temp_dir().join(format!("baton-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("temp file");
    path.to_string_lossy().into_owned()
}

/// A vendor export in Latin-1 (`à` in a comment, 0xE0): read as Windows-1252 with a warning at its place, with
/// and without --json; a file that cannot be read still gets its JSON object.
#[test]
fn charts_in_latin1_and_utf16_are_read_and_said_so() {
    let latin = b"PROGRAM P\n(* r\xE9glage \xE0 la main *)\nINITIAL_STEP S0: END_STEP\nEND_PROGRAM\n";
    let path = temp_bytes("latin1.st", latin);
    let out = baton(&["check", &path]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{err}");
    assert!(
        err.contains("latin1.st:2:5: warning: the file is not UTF-8 (byte 0xE9 here): read as Windows-1252"),
        "{err}"
    );
    let json = baton(&["check", "--json", &path]);
    let v: serde_json::Value = serde_json::from_slice(&json.stdout).expect("one JSON object");
    assert_eq!(v["charts"][0]["pou"], "P");
    assert_eq!(v["diagnostics"][0]["severity"], "warning");
    assert_eq!((v["diagnostics"][0]["line"].as_u64(), v["diagnostics"][0]["col"].as_u64()), (Some(2), Some(5)));
    // UTF-16 with a byte-order mark, as some Windows tools save XML.
    let text = "PROGRAM P\n(* \u{e0} *)\nINITIAL_STEP S0: END_STEP\nEND_PROGRAM\n";
    let utf16: Vec<u8> = [0xFF, 0xFE].into_iter().chain(text.encode_utf16().flat_map(u16::to_le_bytes)).collect();
    let out = baton(&["check", &temp_bytes("utf16.st", &utf16)]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    // Nothing to read: still one JSON object, with the error in it, and baton check's exit status.
    let missing = baton(&["check", "--json", "/nonexistent/chart.st"]);
    assert_eq!(missing.status.code(), Some(2));
    let v: serde_json::Value = serde_json::from_slice(&missing.stdout).expect("one JSON object");
    assert_eq!(v["diagnostics"][0]["severity"], "error");
    assert!(v["diagnostics"][0]["message"].as_str().is_some_and(|m| m.contains("cannot read")), "{v}");
}

/// One size limit for every chart: a chart past it is refused by `baton check` and by `baton run` before
/// anything starts, where an agent would otherwise have refused it for ever.
#[test]
fn a_chart_past_the_size_limit_is_refused_before_anything_starts() {
    let max = baton_proto::limits::SOURCE_BYTES_MAX;
    let big = format!("PROGRAM P\n(* {} *)\nINITIAL_STEP S0: END_STEP\nEND_PROGRAM\n", "x".repeat(max));
    let path = temp_file("huge.st", &big);
    let out = baton(&["check", &path]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains(&format!("more than the {} MiB", max >> 20)));
    let run = baton(&["run", &path, "--listen", "tcp/127.0.0.1:0"]);
    assert_eq!(run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&run.stderr).contains(&format!("more than the {} MiB", max >> 20)));
    // A cycle period no run could have.
    let forever = baton(&["sim", &repo("examples/tank.st"), "--cycle-ms", &u64::MAX.to_string()]);
    assert_eq!(forever.status.code(), Some(2));
    let forever = baton(&["run", &repo("examples/tank.st"), "--listen", "tcp/127.0.0.1:0", "--cycle-ms", "3600001"]);
    assert_eq!(forever.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&forever.stderr).contains("--cycle-ms"));
}

/// Values that would wrap: an array over the whole of LINT (PLCopen), a date whose year has 19 digits, and
/// repetition counts that would expand to billions of initial values — each a located error, at once.
#[test]
fn sizes_and_dates_that_would_wrap_are_errors_at_their_place() {
    let date = temp_file(
        "date.st",
        "PROGRAM P\nVAR d : DATE := D#9223372036854775807-01-01; END_VAR\nINITIAL_STEP S0: END_STEP\nEND_PROGRAM\n",
    );
    let out = baton(&["check", &date]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("date.st:2:17: error: invalid literal: expected a date"), "{err}");
    let feb = temp_file(
        "feb.st",
        "PROGRAM P\nVAR d : DATE := D#2026-02-30; END_VAR\nINITIAL_STEP S0: END_STEP\nEND_PROGRAM\n",
    );
    assert_eq!(baton(&["check", &feb]).status.code(), Some(1));
    let repeated = temp_file(
        "repeat.st",
        "PROGRAM P\nVAR a : ARRAY[0..9] OF INT := [1000000000(1), 1000000000(2), 9223372036854775807(3)]; END_VAR\n\
         INITIAL_STEP S0: END_STEP\nEND_PROGRAM\n",
    );
    let out = baton(&["check", &repeated]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("repeat.st:2:43: error: array `a` has 10 elements, and more initial values"), "{err}");
    let xml = |dims: &str, value: &str| {
        format!(
            "<?xml version=\"1.0\"?><project xmlns=\"http://www.plcopen.org/xml/tc6_0201\"><types><pous>\
             <pou name=\"P\" pouType=\"program\"><interface><localVars><variable name=\"a\"><type><array>{dims}\
             <baseType><INT/></baseType></array></type><initialValue><arrayValue>{value}</arrayValue></initialValue>\
             </variable></localVars></interface><body><SFC><step localId=\"1\" name=\"S0\" initialStep=\"true\">\
             <position x=\"0\" y=\"0\"/></step></SFC></body></pou></pous></types></project>"
        )
    };
    let lint = temp_file(
        "lint.xml",
        &xml(
            "<dimension lower=\"-9223372036854775808\" upper=\"9223372036854775807\"/>",
            "<value><simpleValue value=\"1\"/></value>",
        ),
    );
    let out = baton(&["check", &lint]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("has more elements than the 1000000 Baton holds"), "{err}");
    let runs = temp_file(
        "runs.xml",
        &xml(
            "<dimension lower=\"0\" upper=\"9\"/>",
            "<value repetitionValue=\"18446744073709551615\"><simpleValue value=\"1\"/></value>",
        ),
    );
    let out = baton(&["check", &runs]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("has 10 elements, and more initial values"), "{err}");
}

/// `baton sim` runs no skills: a chart whose steps wait on skills stalls there, and the end of the run says which
/// steps wait on which skill and how to drive them (the indicator to set in an input script), rather than
/// stopping in silence; driven that way, the chart goes on.
#[test]
fn sim_says_which_steps_wait_on_skills_and_how_to_drive_them() {
    let cell = repo("examples/cell.st");
    let out = baton(&["sim", &cell, "--until-ms", "2000"]);
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    for (step, action, indicator) in [("Pick1", "PickPart1", "picked1"), ("Pick2", "PickPart2", "picked2")] {
        let line = err.lines().find(|l| l.contains(&format!("step `{step}`"))).unwrap_or_else(|| panic!("{err}"));
        assert!(line.contains(&format!("action `{action}`")) && line.contains("skill `motion`"), "{line}");
        assert!(line.contains(&format!("`{indicator}`")) && line.contains("baton test"), "{line}");
    }
    // What it says to do works: the indicators set, both picks end.
    let inputs = temp_file("picks.jsonl", "{\"t_ms\": 500, \"set\": {\"picked1\": true, \"picked2\": true}}\n");
    let out = baton(&["sim", &cell, "--until-ms", "2000", "--inputs", &inputs]);
    let trace = String::from_utf8_lossy(&out.stdout);
    assert!(trace.contains("\"name\":\"Picked1\"") && trace.contains("\"name\":\"Picked2\""), "{trace}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("step `Pick1`"), "{err}");
}

/// Every argument and option of every command says what it is in `--help`: a bare `--connect <ENDPOINT>` or
/// `<CHART>` leaves a new user guessing.
#[test]
fn every_argument_of_every_command_has_help_text() {
    let commands: &[&[&str]] = &[
        &["check"],
        &["sim"],
        &["export"],
        &["run"],
        &["replay"],
        &["set"],
        &["test"],
        &["demo"],
        &["bench"],
        &["status"],
        &["ctl"],
        &["deploy", "certs"],
        &["deploy", "acl"],
    ];
    let mut bare = Vec::new();
    for command in commands {
        let mut args = command.to_vec();
        args.push("--help");
        let out = baton(&args);
        assert!(out.status.success(), "{args:?}");
        let help = String::from_utf8_lossy(&out.stdout).to_string();
        let mut listing = false;
        let lines: Vec<&str> = help.lines().collect();
        for (i, line) in lines.iter().enumerate() {
            if line.ends_with(':') && !line.starts_with(' ') {
                listing = *line == "Arguments:" || *line == "Options:";
                continue;
            }
            let item = line.trim_start();
            // An entry is its flag or name, then its help: after two or more spaces on its line, or (when clap
            // lays the help out long) on the next line, indented deeper.
            if listing && (item.starts_with('-') || item.starts_with('<') || item.starts_with('[')) {
                let beside = item.split("  ").map(str::trim).filter(|p| !p.is_empty()).count() > 1;
                let indent = |l: &str| l.len() - l.trim_start().len();
                let below = lines.get(i + 1).is_some_and(|next| {
                    let text = next.trim_start();
                    !text.is_empty() && indent(next) > indent(line) && !text.starts_with('-')
                });
                if !beside && !below {
                    bare.push(format!("baton {}: {item}", command.join(" ")));
                }
            }
        }
    }
    assert!(bare.is_empty(), "arguments without help:\n{}", bare.join("\n"));
}
