//! `baton-agent` as a user starts it: bad arguments get a clear error and a usage exit code.

use std::process::Command;

fn agent(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_baton-agent")).args(args).output().expect("baton-agent runs")
}

#[test]
fn invalid_names_are_refused_before_connecting() {
    let out = agent(&["--connect", "tcp/127.0.0.1:1", "--name", "robot/1"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("`robot/1` is not a valid agent name"));
    let out = agent(&["--connect", "tcp/127.0.0.1:1", "--name", "ok", "--role", "pick*"]);
    assert_eq!(out.status.code(), Some(2));
    let out = agent(&["--connect", "tcp/127.0.0.1:1", "--name", "coordinator"]);
    assert_eq!(out.status.code(), Some(2), "the coordinator's publisher name is reserved");
}

#[test]
fn the_router_endpoint_is_required() {
    let out = agent(&["--name", "robot1"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--connect"));
}

/// An agent whose router does not answer keeps trying (a robot may boot before the cell's network) and says so
/// on stderr, instead of sitting silent.
#[test]
fn an_agent_without_its_router_says_that_it_waits() {
    use std::io::{BufRead, BufReader};
    // A port that nothing listens on: bound, then released.
    let port = std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).expect("a free port").port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut child = Command::new(env!("CARGO_BIN_EXE_baton-agent"))
        .args(["--connect", &endpoint, "--name", "early"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("baton-agent starts");
    let stderr = child.stderr.take().expect("stderr");
    let first = BufReader::new(stderr).lines().next().and_then(Result::ok).unwrap_or_default();
    let _ = child.kill();
    let _ = child.wait();
    assert!(first.contains("no router answers at") && first.contains(&endpoint), "{first}");
}
