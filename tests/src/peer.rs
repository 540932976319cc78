//! Device servers of the tests (ROS 2, OPC UA), written by others: a process whose stdout says what it saw.

use std::path::{Path, PathBuf};
use std::process::Stdio;

use tokio::io::{AsyncBufReadExt, BufReader, Lines};
use tokio::process::{Child, ChildStdout, Command};

use crate::loopback::{free_port, repo, TIMEOUT};

/// A server process whose stdout says what it saw, one line per event; its stdin held open (it serves until
/// stdin closes) and it is killed when dropped.
pub struct Server {
    child: Child,
    lines: Lines<BufReader<ChildStdout>>,
    seen: Vec<String>,
}

impl Server {
    pub fn start(mut cmd: Command) -> Server {
        let mut child = cmd
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .kill_on_drop(true)
            .spawn()
            .expect("start the server");
        let lines = BufReader::new(child.stdout.take().expect("stdout")).lines();
        Server { child, lines, seen: Vec::new() }
    }

    /// Reads until a line starting with `prefix`, under the timeout.
    pub async fn wait_for(&mut self, prefix: &str) -> String {
        let found = tokio::time::timeout(TIMEOUT, async {
            while let Ok(Some(line)) = self.lines.next_line().await {
                self.seen.push(line.clone());
                if line.starts_with(prefix) {
                    return Some(line);
                }
            }
            None
        })
        .await;
        match found {
            Ok(Some(line)) => line,
            _ => panic!("the server never said `{prefix}`; it said:\n{}", self.seen.join("\n")),
        }
    }

    /// Reads until a line starting with each of `prefixes` was seen, in any order (what two publishers send
    /// comes in either order), under the timeout.
    pub async fn wait_for_all(&mut self, prefixes: &[&str]) {
        let mut left: Vec<&str> = prefixes.to_vec();
        let found = tokio::time::timeout(TIMEOUT, async {
            while let Ok(Some(line)) = self.lines.next_line().await {
                self.seen.push(line.clone());
                left.retain(|p| !line.starts_with(p));
                if left.is_empty() {
                    return true;
                }
            }
            false
        })
        .await;
        assert!(matches!(found, Ok(true)), "the server never said {left:?}; it said:\n{}", self.seen.join("\n"));
    }

    /// Writes a line to the server's stdin (a command to the device it plays).
    pub async fn send(&mut self, line: &str) {
        use tokio::io::AsyncWriteExt;
        let stdin = self.child.stdin.as_mut().expect("the server's stdin is open");
        stdin.write_all(format!("{line}\n").as_bytes()).await.expect("write to the server");
        stdin.flush().await.expect("flush to the server");
    }

    /// SIGKILLs the server and waits until it is gone.
    pub async fn kill(&mut self) {
        self.child.start_kill().expect("kill the server");
        let _ = tokio::time::timeout(TIMEOUT, self.child.wait()).await.expect("the killed server ends");
    }

    /// Everything the server said: its stdin is closed (it serves until then) and its output read to the end.
    pub async fn finish(mut self) -> Vec<String> {
        drop(self.child.stdin.take());
        let rest = tokio::time::timeout(TIMEOUT, async {
            while let Ok(Some(line)) = self.lines.next_line().await {
                self.seen.push(line);
            }
        })
        .await;
        assert!(rest.is_ok(), "the server did not end when its stdin closed; it said:\n{}", self.seen.join("\n"));
        self.seen
    }
}

/// A test that needs python3 to import `module` (from the PyPI `package`): without it the test is ignored with
/// the reason (under CI it fails).
pub fn require_python(module: &str, package: &str) {
    let ok = std::process::Command::new("python3")
        .args(["-c", &format!("import {module}")])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        crate::missing(&format!("python3 with {package} is absent: run .ci/run once"));
    }
}

/// FreeOpcUa's asyncua server (`tests/scripts/opcua_server.py`) on a free loopback port, once it is up (the test
/// is ignored, or fails under CI, without asyncua).
pub async fn opcua_server() -> (Server, u16) {
    let port = free_port();
    (opcua_server_on(port).await, port)
}

/// The same on `port` (a server that comes back where it was).
pub async fn opcua_server_on(port: u16) -> Server {
    require_python("asyncua", "asyncua");
    let mut cmd = Command::new("python3");
    cmd.arg(repo("tests/scripts/opcua_server.py")).arg(port.to_string());
    let mut server = Server::start(cmd);
    server.wait_for("READY").await;
    server
}

/// A copy of `chart` in `dir` whose OPC UA endpoints name `port` instead of 4840.
pub fn with_opcua_port(chart: &Path, dir: &Path, port: u16) -> PathBuf {
    let text = std::fs::read_to_string(chart).expect("read the chart");
    let path = dir.join(chart.file_name().expect("a chart file"));
    std::fs::write(&path, text.replace("127.0.0.1:4840/", &format!("127.0.0.1:{port}/"))).expect("write the chart");
    path
}
