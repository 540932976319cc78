//! The Zenoh session configuration every Baton process uses, as JSON5 text for `zenoh::Config::from_json5`:
//! built here once so that the coordinator, the agent and the tools agree (proto itself has no Zenoh).
//!
//! Multicast scouting is off unless asked for: a run joins exactly the endpoints it is given.

use serde_json::json;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Embeds a router: `--listen`.
    Router,
    /// Joins a router: `--connect`.
    Client,
}

/// How long a client that does not wait for its router (`baton status`, `set`, `ctl`) tries to reach it before it
/// says that nothing answers: an operator at a terminal waits seconds, not ten.
pub const CLIENT_CONNECT_TIMEOUT_MS: u64 = 2_500;

/// Batches in each link's queue of data-priority messages (Zenoh's default is 2; 16 is its most). Baton's puts are
/// express and blocking: each leaves in a batch of its own, and a put finding its link's batches all on their way
/// waits for the link's sending task. With 2, a coordinator that sends several messages to one agent at once (a
/// journal commit's, a divergence's) waited on a loaded machine for that task to be scheduled — 400 µs a commit,
/// and 20 % of the throughput without the journal (`docs/book/src/benchmarks.md`). A batch is allocated at
/// Zenoh's batch size but only the bytes of its messages are touched.
pub const TX_QUEUE_DATA: u32 = 16;

#[derive(Clone, Debug)]
pub struct NetConfig {
    pub mode: Mode,
    pub listen: Vec<String>,
    pub connect: Vec<String>,
    /// The lease this process announces: a peer that hears nothing from it for this long drops it.
    pub lease_ms: Option<u64>,
    /// Keep retrying to connect (long-running processes) rather than failing at once (one-shot tools).
    pub wait_for_router: bool,
    pub multicast_scouting: bool,
}

impl NetConfig {
    /// A router listening on `listen`, as `--listen` and `baton demo` embed one.
    pub fn router(listen: &[String]) -> NetConfig {
        NetConfig {
            mode: Mode::Router,
            listen: listen.to_vec(),
            connect: Vec::new(),
            lease_ms: None,
            wait_for_router: false,
            multicast_scouting: false,
        }
    }

    /// A client of the router at `connect`: long-running processes wait for it, one-shot tools fail at once.
    /// A client of `connect`'s routers; one that does not wait for them (`baton status`, `set`, `ctl`) gives up
    /// after `CLIENT_CONNECT_TIMEOUT_MS`.
    pub fn client(connect: &[String], wait_for_router: bool) -> NetConfig {
        NetConfig {
            mode: Mode::Client,
            listen: Vec::new(),
            connect: connect.to_vec(),
            lease_ms: None,
            wait_for_router,
            multicast_scouting: false,
        }
    }

    /// The settings Baton imposes on a user's own Zenoh configuration file (TLS, authentication…), as
    /// `(key, JSON5 value)` pairs for `zenoh::Config::insert_json5`.
    pub fn overrides(&self) -> Vec<(&'static str, String)> {
        let v: serde_json::Value = match serde_json::from_str(&self.json5()) {
            Ok(v) => v,
            Err(_) => return Vec::new(),
        };
        let mut out = vec![
            ("mode", v["mode"].to_string()),
            ("listen/endpoints", v["listen"]["endpoints"].to_string()),
            ("connect/endpoints", v["connect"]["endpoints"].to_string()),
            ("connect/timeout_ms", v["connect"]["timeout_ms"].to_string()),
            ("connect/exit_on_failure", v["connect"]["exit_on_failure"].to_string()),
            ("scouting/multicast/enabled", v["scouting"]["multicast"]["enabled"].to_string()),
            ("transport/link/tx/queue/size/data", TX_QUEUE_DATA.to_string()),
        ];
        if let Some(lease) = self.lease_ms {
            out.push(("transport/link/tx/lease", lease.to_string()));
        }
        out
    }

    pub fn json5(&self) -> String {
        let mode = match self.mode {
            Mode::Router => "router",
            Mode::Client => "client",
        };
        let mut cfg = json!({
            "mode": mode,
            "listen": { "endpoints": self.listen },
            "connect": {
                "endpoints": self.connect,
                "timeout_ms": if self.wait_for_router { -1 } else { CLIENT_CONNECT_TIMEOUT_MS as i64 },
                "exit_on_failure": !self.wait_for_router,
                "retry": { "period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2 },
            },
            "scouting": {
                "multicast": { "enabled": self.multicast_scouting },
                "gossip": { "enabled": true },
            },
        });
        cfg["transport"] = json!({ "link": { "tx": { "queue": { "size": { "data": TX_QUEUE_DATA } } } } });
        if let Some(lease) = self.lease_ms {
            cfg["transport"]["link"]["tx"]["lease"] = json!(lease);
        }
        cfg.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scouting_is_off_and_the_lease_is_set() {
        let cfg = NetConfig {
            mode: Mode::Client,
            listen: vec![],
            connect: vec!["tcp/127.0.0.1:7447".into()],
            lease_ms: Some(2000),
            wait_for_router: true,
            multicast_scouting: false,
        };
        let v: serde_json::Value = serde_json::from_str(&cfg.json5()).unwrap();
        assert_eq!(v["scouting"]["multicast"]["enabled"], false);
        assert_eq!(v["transport"]["link"]["tx"]["lease"], 2000);
        assert_eq!(v["connect"]["timeout_ms"], -1);
        let overrides = cfg.overrides();
        assert!(overrides.contains(&("mode", "\"client\"".to_string())));
        assert!(overrides.contains(&("transport/link/tx/lease", "2000".to_string())));
        assert!(overrides.contains(&("scouting/multicast/enabled", "false".to_string())));
        assert_eq!(v["transport"]["link"]["tx"]["queue"]["size"]["data"], TX_QUEUE_DATA);
        assert!(overrides.contains(&("transport/link/tx/queue/size/data", TX_QUEUE_DATA.to_string())));
    }
}
