//! The nesting limit, proved at the limit: for every way a chart's code nests, the deepest chart `baton check`
//! accepts is within a few levels of `NESTING_DEPTH_MAX` (the limit is not stricter than it says), one level more
//! is an error at a line and column that names the limit (never a stack overflow), and a chart made of every
//! kind at its deepest runs to the end on a real agent and in `baton test`, with the values `baton sim` computes.
//! Inputs far past the limit (50,000 operators, 20,000 nested calls) cost nothing either.

use baton_proto::limits::NESTING_DEPTH_MAX;
use baton_proto::pipeline::check_source;
use baton_tests::loopback::{bin, Cluster};

/// One way code nests, `k` levels deep: what it adds before the program, to its variables, and as an action's
/// body or a transition's condition; `n` is the counter it writes.
struct Form {
    name: &'static str,
    build: fn(usize, &str) -> Part,
}

#[derive(Default)]
struct Part {
    prelude: String,
    vars: String,
    body: Option<String>,
    condition: Option<String>,
}

fn body(text: String) -> Part {
    Part { body: Some(text), ..Part::default() }
}

const FORMS: &[Form] = &[
    Form { name: "NOT", build: |k, _| Part { condition: Some(format!("{}x", "NOT ".repeat(k))), ..Part::default() } },
    Form {
        name: "parentheses",
        build: |k, _| Part { condition: Some(format!("{}x{}", "(".repeat(k), ")".repeat(k))), ..Part::default() },
    },
    Form { name: "calls", build: |k, n| body(format!("{n} := {}{n} + 1{};", "ABS(".repeat(k), ")".repeat(k))) },
    Form { name: "indices", build: |k, n| body(format!("{n} := {n} + {}1{};", "a[".repeat(k), "]".repeat(k))) },
    Form { name: "a chain of minus", build: |k, n| body(format!("{n} := {n}{};", " - 1".repeat(k))) },
    Form {
        name: "IF statements",
        build: |k, n| body(format!("{}{n} := {n} + 1;{}", "IF x THEN ".repeat(k), " END_IF;".repeat(k))),
    },
    Form {
        name: "function block instances",
        build: |k, n| {
            let mut prelude = String::new();
            for i in 0..k {
                let (inner, call) = match i + 1 < k {
                    true => (format!("i : {n}_FB{};", i + 1), "i();".to_string()),
                    false => (String::new(), format!("{n} := {n} + 1;")),
                };
                prelude.push_str(&format!(
                    "FUNCTION_BLOCK {n}_FB{i}\nVAR_EXTERNAL {n} : INT; END_VAR\nVAR {inner} END_VAR\n{call}\nEND_FUNCTION_BLOCK\n"
                ));
            }
            Part { prelude, vars: format!("{n}_top : {n}_FB0;"), body: Some(format!("{n}_top();")), condition: None }
        },
    },
    Form {
        name: "function calls",
        build: |k, n| {
            let mut prelude = String::new();
            for i in 0..k {
                let result = match i + 1 < k {
                    true => format!("{n}_F{i} := {n}_F{}(v) + 1;", i + 1),
                    false => format!("{n}_F{i} := v;"),
                };
                prelude.push_str(&format!(
                    "FUNCTION {n}_F{i} : INT\nVAR_INPUT v : INT; END_VAR\n{result}\nEND_FUNCTION\n"
                ));
            }
            Part { prelude, body: Some(format!("{n} := {n}_F0(1);")), ..Part::default() }
        },
    },
];

/// A chart with one form `k` deep: its condition between Start and Work, or its body as an action of Work,
/// which runs on agent a1.
fn chart(parts: &[(String, Part)]) -> String {
    let mut prelude = String::new();
    let mut vars = String::new();
    let mut assocs = String::new();
    let mut actions = String::new();
    let mut conditions = Vec::new();
    for (n, p) in parts {
        prelude.push_str(&p.prelude);
        vars.push_str(&format!(" {n} : INT := 1; {}", p.vars));
        if let Some(b) = &p.body {
            assocs.push_str(&format!("Do_{n}(N); "));
            actions.push_str(&format!("ACTION Do_{n}: {b} END_ACTION\n"));
        }
        conditions.extend(p.condition.clone());
    }
    let mut net = String::from("INITIAL_STEP Start: END_STEP\n");
    let mut from = "Start".to_string();
    for (i, c) in conditions.iter().enumerate() {
        net.push_str(&format!("TRANSITION FROM {from} TO Gate{i} := {c}; END_TRANSITION\nSTEP Gate{i}: END_STEP\n"));
        from = format!("Gate{i}");
    }
    net.push_str(&format!(
        "TRANSITION FROM {from} TO Work := TRUE; END_TRANSITION\nSTEP Work: {{agent := 'a1'}} {assocs}END_STEP\n\
         TRANSITION FROM Work TO Done := Work.T >= T#50ms; END_TRANSITION\nSTEP Done: END_STEP\n"
    ));
    format!("{prelude}PROGRAM deep\nVAR x : BOOL := TRUE; a : ARRAY[0..3] OF INT := [0, 1, 2, 3];{vars} END_VAR\n{net}{actions}END_PROGRAM\n")
}

fn valid(src: &str) -> Result<(), String> {
    let report = check_source(src);
    match report.diagnostics.iter().find(|d| d.is_error()) {
        None => Ok(()),
        Some(d) => {
            let index = baton_proto::front::diag::LineIndex::new(src);
            Err(index.render("deep.st", d))
        }
    }
}

/// The deepest `k` of `form` that checks valid (it must at 1).
fn deepest(form: &Form) -> usize {
    let at = |k: usize| valid(&chart(&[("n".to_string(), (form.build)(k, "n"))])).is_ok();
    assert!(at(1), "{}: one level is refused: {:?}", form.name, valid(&chart(&[("n".into(), (form.build)(1, "n"))])));
    let (mut ok, mut bad) = (1, 4 * NESTING_DEPTH_MAX);
    assert!(!at(bad), "{}: {bad} levels are accepted", form.name);
    while bad - ok > 1 {
        let mid = (ok + bad) / 2;
        if at(mid) {
            ok = mid;
        } else {
            bad = mid;
        }
    }
    ok
}

#[test]
fn every_kind_of_nesting_is_refused_one_level_past_the_limit_at_its_place() {
    for form in FORMS {
        let k = deepest(form);
        assert!(
            (NESTING_DEPTH_MAX - 4..=NESTING_DEPTH_MAX + 1).contains(&k),
            "{}: the deepest accepted is {k}, the limit says {NESTING_DEPTH_MAX}",
            form.name
        );
        let err = valid(&chart(&[("n".to_string(), (form.build)(k + 1, "n"))])).expect_err("one more is refused");
        assert!(err.contains(&format!("more than {NESTING_DEPTH_MAX}")), "{}: {err}", form.name);
        // FILE:LINE:COL, with a line past the first (the place, not the file).
        let place: Vec<&str> = err.splitn(4, ':').collect();
        assert!(place[1].parse::<usize>().is_ok_and(|l| l >= 1) && place[2].parse::<usize>().is_ok(), "{err}");
    }
}

#[test]
fn far_past_the_limit_costs_nothing() {
    // 50,000 ANDs are a balanced tree (16 levels): valid. The others are errors, found at once.
    let ands = format!("x{}", " AND x".repeat(50_000));
    assert_eq!(valid(&chart(&[("n".into(), Part { condition: Some(ands), ..Part::default() })])), Ok(()));
    for form in FORMS {
        let k = if form.name.contains("function") { 6_000 } else { 20_000 };
        let err = valid(&chart(&[("n".to_string(), (form.build)(k, "n"))])).expect_err("refused");
        assert!(err.contains(&format!("more than {NESTING_DEPTH_MAX}")), "{}: {err}", form.name);
    }
}

#[test]
fn plcopen_logic_and_macro_steps_nest_within_the_limit_too() {
    use baton_tests::gen::{plcopen_contacts, plcopen_macro};
    let xml_valid = |xml: &str| {
        let report = check_source(xml);
        match report.diagnostics.iter().find(|d| d.is_error()) {
            None => Ok(()),
            Some(d) => Err(baton_proto::front::diag::LineIndex::new(xml).render("deep.xml", d)),
        }
    };
    // A coil fed by 30,000 parallel contacts is a balanced OR: valid, and it runs.
    let parallel = plcopen_contacts(30_000, true);
    assert_eq!(xml_valid(&parallel), Ok(()));
    // Contacts in series nest one level each; macro steps in macro steps too.
    assert_eq!(xml_valid(&plcopen_contacts(NESTING_DEPTH_MAX - 4, false)), Ok(()));
    for xml in [plcopen_contacts(NESTING_DEPTH_MAX + 1, false), plcopen_macro(6_000, true)] {
        let err = xml_valid(&xml).expect_err("refused");
        assert!(err.contains(&format!("more than {NESTING_DEPTH_MAX}")), "{err}");
        assert!(err.starts_with("deep.xml:") && !err.starts_with("deep.xml:1:1:"), "at its place: {err}");
    }
    assert_eq!(xml_valid(&plcopen_macro(NESTING_DEPTH_MAX - 1, true)), Ok(()));
}

/// Every kind at its deepest in one chart, each in an action of its own on a1 (or a transition's condition).
fn deepest_chart() -> (String, Vec<String>) {
    let parts: Vec<(String, Part)> =
        FORMS.iter().enumerate().map(|(i, f)| (format!("n{i}"), (f.build)(deepest(f), &format!("n{i}")))).collect();
    let names = parts.iter().map(|(n, _)| n.clone()).collect();
    (chart(&parts), names)
}

#[tokio::test(flavor = "multi_thread")]
async fn the_deepest_chart_baton_check_accepts_runs_on_an_agent_and_in_baton_test() {
    let (source, names) = deepest_chart();
    assert_eq!(valid(&source), Ok(()), "the deepest of every kind together");
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let expected = baton_tests::reference::final_shown(&source, 10, &refs);
    // The conditions' counters stay 1; every action changed its own.
    assert!(expected[2..].iter().all(|v| v != "1"), "every action ran: {expected:?}");

    // A real agent fetches the chart, compiles it on its own threads and runs the actions.
    let mut cluster = Cluster::new();
    let path = cluster.dir.path().join("deep.st");
    std::fs::write(&path, &source).expect("write the chart");
    cluster.agent("a1", &[], &[]);
    let (status, log, _, summary) = cluster.coordinator(&path, &[]).finish().await;
    assert!(status.success(), "{log}\n{}", cluster.agent_log("a1"));
    let got: Vec<String> = names.iter().map(|n| summary["vars"][n].as_str().unwrap_or("?").to_string()).collect();
    assert_eq!(got, expected, "{names:?}");

    // baton test runs it on its worker threads, and the values are those of baton sim.
    let values: Vec<String> = names.iter().zip(&expected).map(|(n, v)| format!("{n} = {v}")).collect();
    let scenario = format!(
        "chart = \"deep.st\"\n\n[[agents]]\nname = \"a1\"\n\n[[expect]]\nstate = \"finished\"\n\n[[expect]]\nvalue = {{ {} }}\n",
        values.join(", ")
    );
    std::fs::write(cluster.dir.path().join("deep.test.toml"), scenario).expect("write the scenario");
    let out = tokio::process::Command::new(bin("baton"))
        .args(["test", "deep.test.toml", "--out"])
        .arg(cluster.dir.path().join("out"))
        .current_dir(cluster.dir.path())
        .output()
        .await
        .expect("baton test runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
}
