//! A systemd unit of `deploy/systemd/` as systemd would run it: its settings read, its `ExecStart` filled in for an
//! instance — `/etc/baton/` and `/var/lib/baton/` put in the test's folder, the binary the build's, the variables
//! of its environment file given — and started with its log read line by line.

use std::path::Path;

use crate::loopback::{self, bin};

/// A line of the unit file: the value of its `KEY=`.
pub fn setting(unit: &str, key: &str) -> String {
    let prefix = format!("{key}=");
    let line = unit.lines().find(|l| l.starts_with(&prefix)).unwrap_or_else(|| panic!("the unit has no {key}"));
    line[prefix.len()..].to_string()
}

/// The unit's `ExecStart` for `instance`, its environment file's `vars` (`("BATON_ROUTER", "tcp/…")`) put in for
/// `${NAME}` and `$NAME`. Every placeholder must be filled.
pub fn command(unit: &str, dir: &Path, instance: &str, vars: &[(&str, &str)]) -> Vec<String> {
    let mut line = setting(unit, "ExecStart")
        .replace("%i", instance)
        .replace("/usr/local/bin/baton", bin("baton").to_str().expect("utf-8"))
        .replace("/etc/baton/", &format!("{}/etc/", dir.display()))
        .replace("/var/lib/baton/", &format!("{}/var/", dir.display()));
    for (name, value) in vars {
        line = line.replace(&format!("${{{name}}}"), value).replace(&format!("${name}"), value);
    }
    assert!(!line.contains(['$', '%']), "the unit's command line has more to fill in: {line}");
    line.split_whitespace().map(str::to_string).collect()
}

/// Starts the unit's command (its stderr read line by line), as `loopback::Coordinator`.
pub fn start(command: &[String], trace: &Path, summary: &Path) -> loopback::Coordinator {
    let trace_before = loopback::fresh_trace(trace, &command.iter().map(String::as_str).collect::<Vec<_>>());
    let child = tokio::process::Command::new(&command[0])
        .args(&command[1..])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("start the unit's command");
    loopback::Coordinator::following(child, trace.to_path_buf(), summary.to_path_buf(), trace_before)
}
