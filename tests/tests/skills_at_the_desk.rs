//! A misspelt skill is found at the desk: `baton check` knows the skills `baton-agent` ships and their parameters,
//! and those a `--skills FILE` lists — as `baton-agent --list-skills` prints them for the options an agent runs
//! with — or the agents live behind a router announce (`--connect`), and warns of any other name with the
//! nearest known one.

use std::process::{Command, Output};

use baton_tests::loopback::{bin, Cluster, TIMEOUT};

fn run(name: &str, args: &[&str]) -> (Output, String, String) {
    let o = Command::new(bin(name)).args(args).output().expect("runs");
    let (out, err) = (String::from_utf8_lossy(&o.stdout).to_string(), String::from_utf8_lossy(&o.stderr).to_string());
    (o, out, err)
}

const CHART: &str = "PROGRAM cell\nVAR picked, closed : BOOL; END_VAR\n\
    ACTION Pick: {skill := 'motoin', ms := 800} END_ACTION\n\
    ACTION Place: {skill := 'motion', mss := 800} END_ACTION\n\
    ACTION Close: {skill := 'grip', force := 20} END_ACTION\n\
    ACTION Beep: {skill := 'shell', cmd := 'beep'} END_ACTION\n\
    INITIAL_STEP Home: END_STEP\nTRANSITION FROM Home TO Work := TRUE; END_TRANSITION\n\
    STEP Work: {agent := 'robot1'} Pick(N, picked); Place(N); Close(N, closed); Beep(N); END_STEP\n\
    TRANSITION FROM Work TO Done := picked AND closed; END_TRANSITION\nSTEP Done: END_STEP\nEND_PROGRAM\n";

#[test]
fn check_warns_of_skills_and_parameters_no_agent_has_with_the_nearest_known_name() {
    let dir = tempfile::tempdir().expect("tmp");
    let chart = dir.path().join("cell.st");
    std::fs::write(&chart, CHART).expect("write");
    let chart = chart.to_str().expect("utf-8");
    let (o, out, err) = run("baton", &["check", chart]);
    assert_eq!(o.status.code(), Some(0), "warnings keep exit 0: {out}{err}");
    assert!(err.contains("cell.st:3:14: warning: action `Pick` uses skill `motoin`"), "{err}");
    assert!(err.contains("did you mean `motion`?"), "{err}");
    assert!(
        err.contains(
            "cell.st:4:15: warning: skill `motion` of action `Place` has no parameter `mss` (did you mean `ms`?"
        ),
        "{err}"
    );
    assert!(err.contains("action `Close` uses skill `grip`"), "{err}");
    // `shell` is built in (an agent offers it with --allow-shell); `cmd` is its parameter.
    assert!(!err.contains("`Beep`"), "{err}");
    assert!(out.contains("3 warning(s)"), "{out}");
    let (_, json, _) = run("baton", &["check", "--json", chart]);
    let v: serde_json::Value = serde_json::from_str(&json).expect("one JSON object");
    let warned: Vec<&str> = v["diagnostics"]
        .as_array()
        .expect("diagnostics")
        .iter()
        .filter(|d| d["severity"] == "warning")
        .filter_map(|d| d["message"].as_str())
        .collect();
    assert_eq!(warned.len(), 3, "{warned:?}");

    // What an agent says it has: the built-in skills for its options, then a robot program's own `grip`.
    let (o, listed, err) = run("baton-agent", &["--list-skills", "--allow-shell"]);
    assert!(o.status.success(), "{err}");
    assert!(listed.contains("name = \"shell\"") && listed.contains("name = \"motion\""), "{listed}");
    let (_, without_shell, _) = run("baton-agent", &["--list-skills"]);
    assert!(!without_shell.contains("name = \"shell\""), "{without_shell}");
    let agent = dir.path().join("robot1.skills.toml");
    std::fs::write(&agent, &listed).expect("write");
    let grip = dir.path().join("grip.json");
    std::fs::write(&grip, r#"{"skills": [{"name": "grip", "params": ["force", "speed"]}]}"#).expect("write");
    let (o, _, err) =
        run("baton", &["check", chart, "--skills", agent.to_str().unwrap(), "--skills", grip.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(!err.contains("`grip`"), "grip is listed: {err}");
    assert!(err.contains("`motoin`") && err.contains("`mss`"), "the others stand: {err}");

    // A catalogue that cannot be read is a usage error, said with the file's name.
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[[skills]]\nname = \"two words\"\n").expect("write");
    let (o, _, err) = run("baton", &["check", chart, "--skills", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("bad.toml") && err.contains("not a skill name"), "{err}");
}

/// `baton check --connect EP` asks the agents live behind the router which skills they have: a robot program's own
/// skill (`grip`, which an agent simulating a scenario offers) is then known; the misspelt one is still warned of.
#[tokio::test(flavor = "multi_thread")]
async fn check_knows_the_skills_the_live_agents_announce() {
    let mut cluster = Cluster::with_router().await;
    let dir = cluster.dir.path().to_path_buf();
    let grip = "PROGRAM g\nVAR closed : BOOL; END_VAR\nACTION Close: {skill := 'grip', force := 20} END_ACTION\n\
                INITIAL_STEP Home: END_STEP\nTRANSITION FROM Home TO Work := TRUE; END_TRANSITION\n\
                STEP Work: {agent := 'robot1'} Close(N, closed); END_STEP\nEND_PROGRAM\n";
    std::fs::write(dir.join("grip.st"), grip).expect("write");
    let scenario = "chart = \"grip.st\"\n\n[[agents]]\nname = \"robot1\"\n\n[actions.Close]\nduration = \"1s\"\n\n\
                    [[expect]]\nreached = \"Work\"\n";
    std::fs::write(dir.join("grip.test.toml"), scenario).expect("write");
    std::fs::write(dir.join("cell.st"), CHART).expect("write");
    let simulate = dir.join("grip.test.toml");
    cluster.agent("robot1", &[], &["--simulate", simulate.to_str().expect("utf-8")]);
    let cell = dir.join("cell.st");
    let check = || run("baton", &["check", cell.to_str().expect("utf-8"), "--connect", &cluster.endpoint]);
    let deadline = std::time::Instant::now() + TIMEOUT;
    let (o, err) = loop {
        let (o, _, err) = check();
        if err.contains("skills of the live agents (robot1)") {
            break (o, err);
        }
        assert!(std::time::Instant::now() < deadline, "robot1 never answered: {err}");
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    };
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(err.contains("grip") && !err.contains("action `Close` uses skill `grip`"), "{err}");
    assert!(err.contains("action `Pick` uses skill `motoin`"), "{err}");
    // Nothing listens: said in plain words, exit 2.
    let (o, _, err) = run("baton", &["check", cell.to_str().expect("utf-8"), "--connect", "tcp/127.0.0.1:1"]);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("no router answered at tcp/127.0.0.1:1"), "{err}");
}
