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
