//! A real etcd cluster on loopback for the tests of standby coordinators: Debian's `etcd-server` (3.4.23, which
//! `.ci/run` installs), members started by the test on free ports with their data in a temp folder, killed and
//! started again at will, and every one of them killed when the cluster is dropped.

use std::path::PathBuf;
use std::process::Stdio;
use std::time::Duration;

use tokio::process::{Child, Command};

use crate::loopback::{free_port, TIMEOUT};

/// The etcd release the tests are pinned to (Debian bookworm's `etcd-server`).
pub const VERSION: &str = "3.4.23";

pub struct Etcd {
    members: Vec<Member>,
    /// The members' data folders and logs.
    pub dir: tempfile::TempDir,
}

struct Member {
    client: u16,
    /// The client port over TLS, when the cluster has one.
    tls_client: Option<u16>,
    args: Vec<String>,
    child: Option<Child>,
}

/// The `etcd` binary of the pinned version, or the test is missing its peer.
fn etcd() -> PathBuf {
    let path = PathBuf::from("/usr/bin/etcd");
    let version = std::process::Command::new(&path).arg("--version").output();
    match version {
        Ok(out) if String::from_utf8_lossy(&out.stdout).contains(&format!("etcd Version: {VERSION}")) => path,
        Ok(out) => crate::harness::missing(&format!(
            "/usr/bin/etcd is not etcd {VERSION} ({}): apt-get install etcd-server=3.4.23-4+b4",
            String::from_utf8_lossy(&out.stdout).lines().next().unwrap_or("")
        )),
        Err(_) => crate::harness::missing("etcd is not installed: apt-get install etcd-server=3.4.23-4+b4"),
    }
}

impl Etcd {
    /// Starts a cluster of `n` members and returns once it has a leader. A port found free and taken by another
    /// process before a member could bind it (the tests run side by side) is a start on other ports, not a failure.
    pub async fn start(n: usize) -> Etcd {
        Etcd::start_with(n, None, &[]).await
    }

    /// One member whose sign-ins (`enable_auth`) expire after `ttl_s` seconds unused, where etcd's default is 300:
    /// a run outlasts several.
    pub async fn start_short_tokens(ttl_s: u32) -> Etcd {
        Etcd::start_with(1, None, &["--auth-token-ttl".to_string(), ttl_s.to_string()]).await
    }

    /// One member whose client port speaks TLS as a plant's etcd does: its server certificate `certs/etcd.pem`
    /// (with `ca.pem` beside it, as `baton deploy certs --ca CERTS etcd --san 127.0.0.1` makes them), and a client
    /// certificate that CA signed required of every client (`--client-cert-auth`). A second client port without TLS
    /// serves the test's own health checks and JSON gateway.
    pub async fn start_tls(certs: &std::path::Path) -> Etcd {
        Etcd::start_with(1, Some(certs), &[]).await
    }

    async fn start_with(n: usize, tls: Option<&std::path::Path>, extra: &[String]) -> Etcd {
        for _ in 0..4 {
            if let Some(etcd) = Etcd::try_start(n, tls, extra).await {
                return etcd;
            }
        }
        panic!("etcd could not bind free ports in four tries");
    }

    /// A cluster on free ports, or `None` when a member found one of them taken.
    async fn try_start(n: usize, tls: Option<&std::path::Path>, extra: &[String]) -> Option<Etcd> {
        let binary = etcd();
        let dir = tempfile::tempdir().expect("temp dir");
        let ports: Vec<(u16, u16)> = (0..n).map(|_| (free_port(), free_port())).collect();
        let cluster: Vec<String> =
            ports.iter().enumerate().map(|(i, (_, peer))| format!("m{i}=http://127.0.0.1:{peer}")).collect();
        let members = ports
            .iter()
            .enumerate()
            .map(|(i, &(client, peer))| {
                let tls_client = tls.map(|_| free_port());
                let clients = match tls_client {
                    Some(port) => format!("http://127.0.0.1:{client},https://127.0.0.1:{port}"),
                    None => format!("http://127.0.0.1:{client}"),
                };
                let mut args = [
                    "--name".to_string(),
                    format!("m{i}"),
                    "--data-dir".into(),
                    dir.path().join(format!("m{i}")).display().to_string(),
                    "--listen-client-urls".into(),
                    clients.clone(),
                    "--advertise-client-urls".into(),
                    clients,
                    "--listen-peer-urls".into(),
                    format!("http://127.0.0.1:{peer}"),
                    "--initial-advertise-peer-urls".into(),
                    format!("http://127.0.0.1:{peer}"),
                    "--initial-cluster".into(),
                    cluster.join(","),
                    "--initial-cluster-token".into(),
                    "baton-test".into(),
                    "--initial-cluster-state".into(),
                    "new".into(),
                    "--logger".into(),
                    "zap".into(),
                    "--log-level".into(),
                    "warn".into(),
                    // As deploy/etcd/ advises for a cell: a leader lost is replaced well within a coordinator's
                    // lease (the coordinator stops acting two thirds into it without a renewal).
                    "--heartbeat-interval".into(),
                    "50".into(),
                    "--election-timeout".into(),
                    "500".into(),
                ]
                .to_vec();
                if let Some(certs) = tls {
                    let file = |name: &str| certs.join(name).display().to_string();
                    args.extend(["--cert-file".into(), file("etcd.pem"), "--key-file".into(), file("etcd.key")]);
                    args.extend(["--trusted-ca-file".into(), file("ca.pem"), "--client-cert-auth".into()]);
                }
                args.extend(extra.iter().cloned());
                Member { client, tls_client, args, child: None }
            })
            .collect();
        let mut etcd = Etcd { members, dir };
        for i in 0..n {
            etcd.spawn(&binary, i);
        }
        for i in 0..n {
            if !etcd.wait_healthy(i).await {
                return None;
            }
        }
        Some(etcd)
    }

    fn spawn(&mut self, binary: &PathBuf, i: usize) {
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.dir.path().join(format!("m{i}.log")))
            .expect("etcd's log");
        let member = &mut self.members[i];
        let child = Command::new(binary)
            .args(&member.args)
            .stdout(Stdio::null())
            .stderr(log)
            .kill_on_drop(true)
            .spawn()
            .expect("start etcd");
        member.child = Some(child);
    }

    /// Waits until member `i` answers its health check with a leader in its cluster; `false` if it could not bind
    /// its ports (it exits saying so).
    async fn wait_healthy(&mut self, i: usize) -> bool {
        let addr = format!("127.0.0.1:{}", self.members[i].client);
        let up = tokio::time::timeout(TIMEOUT, async {
            loop {
                if tokio::net::TcpStream::connect(&addr).await.is_ok() {
                    let (status, body) = crate::http::http(&addr, "GET", "/health", None).await;
                    if status == 200 && body.contains("\"true\"") {
                        return true;
                    }
                }
                let exited = self.members[i].child.as_mut().is_some_and(|c| c.try_wait().ok().flatten().is_some());
                if exited && self.log(i).contains("address already in use") {
                    return false;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        })
        .await;
        match up {
            Ok(bound) => bound,
            Err(_) => panic!("etcd member m{i} never became healthy: {}", self.log(i)),
        }
    }

    /// Member `i`'s log, for a failure message.
    pub fn log(&self, i: usize) -> String {
        std::fs::read_to_string(self.dir.path().join(format!("m{i}.log"))).unwrap_or_default()
    }

    /// The client endpoints, as `--election etcd://…` names them: `127.0.0.1:P1,127.0.0.1:P2,…`.
    pub fn endpoints(&self) -> String {
        self.members.iter().map(|m| format!("127.0.0.1:{}", m.client)).collect::<Vec<_>>().join(",")
    }

    /// The client endpoints over TLS, as `--election etcds://…` names them.
    pub fn tls_endpoints(&self) -> String {
        let tls = self.members.iter().map(|m| format!("127.0.0.1:{}", m.tls_client.expect("started with TLS")));
        tls.collect::<Vec<_>>().join(",")
    }

    /// The members' client addresses (for a `Cable` to each).
    pub fn client_addrs(&self) -> Vec<std::net::SocketAddr> {
        self.members.iter().map(|m| std::net::SocketAddr::from(([127, 0, 0, 1], m.client))).collect()
    }

    /// The keys under `prefix`, each with the revision that created it, through etcd's JSON gateway (member 0).
    pub async fn keys_under(&self, prefix: &str) -> Vec<(String, u64)> {
        use base64::Engine;
        let b64 = base64::engine::general_purpose::STANDARD;
        let mut end = prefix.as_bytes().to_vec();
        *end.last_mut().expect("a prefix") += 1;
        let body = serde_json::json!({"key": b64.encode(prefix), "range_end": b64.encode(end), "keys_only": true});
        let (status, answer) = self.gateway("/v3/kv/range", &body).await;
        assert_eq!(status, 200, "{answer}");
        let answer: serde_json::Value = serde_json::from_str(&answer).expect("JSON from etcd");
        let kvs = answer["kvs"].as_array().cloned().unwrap_or_default();
        kvs.iter()
            .map(|kv| {
                let key = b64.decode(kv["key"].as_str().expect("a key")).expect("base64");
                let created = kv["create_revision"].as_str().and_then(|r| r.parse().ok()).expect("a revision");
                (String::from_utf8(key).expect("utf-8 key"), created)
            })
            .collect()
    }

    /// Turns etcd's auth on as a plant's administrator does with etcdctl (`user add`, `role add`, `role
    /// grant-permission --prefix … readwrite`, `user grant-role`, `auth enable`): a `root` user, and each of `users`
    /// (name, password, key prefix) with a role of its own that reads and writes the keys under its prefix alone.
    /// From then on etcd answers only a client signed in (the JSON gateway included).
    pub async fn enable_auth(&self, users: &[(&str, &str, &str)]) {
        use base64::Engine;
        let b64 = base64::engine::general_purpose::STANDARD;
        let mut calls = vec![
            ("/v3/auth/user/add", serde_json::json!({"name": "root", "password": "root-password"})),
            ("/v3/auth/user/grant", serde_json::json!({"user": "root", "role": "root"})),
        ];
        for (name, password, prefix) in users {
            let mut end = prefix.as_bytes().to_vec();
            *end.last_mut().expect("a prefix") += 1;
            let role = format!("{name}-role");
            let perm =
                serde_json::json!({"permType": "READWRITE", "key": b64.encode(prefix), "range_end": b64.encode(end)});
            calls.extend([
                ("/v3/auth/role/add", serde_json::json!({"name": role})),
                ("/v3/auth/role/grant", serde_json::json!({"name": role, "perm": perm})),
                ("/v3/auth/user/add", serde_json::json!({"name": name, "password": password})),
                ("/v3/auth/user/grant", serde_json::json!({"user": name, "role": role})),
            ]);
        }
        calls.push(("/v3/auth/enable", serde_json::json!({})));
        for (path, body) in calls {
            let (status, answer) = self.gateway(path, &body).await;
            assert_eq!(status, 200, "{path} {body}: {answer}");
        }
    }

    /// Deletes `key`, as an operator with etcdctl would.
    pub async fn delete(&self, key: &str) {
        use base64::Engine;
        let body = serde_json::json!({"key": base64::engine::general_purpose::STANDARD.encode(key)});
        let (status, answer) = self.gateway("/v3/kv/deleterange", &body).await;
        assert_eq!(status, 200, "{answer}");
        assert!(answer.contains("\"deleted\":\"1\""), "{key} deleted: {answer}");
    }

    async fn gateway(&self, path: &str, body: &serde_json::Value) -> (u16, String) {
        let addr = format!("127.0.0.1:{}", self.members[0].client);
        crate::http::http(&addr, "POST", path, Some(&body.to_string())).await
    }

    /// SIGKILLs member `i` and waits for it to be gone.
    pub async fn kill(&mut self, i: usize) {
        if let Some(mut child) = self.members[i].child.take() {
            child.start_kill().expect("kill etcd");
            tokio::time::timeout(TIMEOUT, child.wait()).await.expect("etcd died in time").expect("wait");
        }
    }

    /// Starts member `i` again on its data (its cluster had it), and returns once it is healthy.
    pub async fn restart(&mut self, i: usize) {
        self.spawn(&etcd(), i);
        assert!(self.wait_healthy(i).await, "etcd member m{i} could not bind its ports again: {}", self.log(i));
    }
}
