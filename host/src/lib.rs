//! What the two binaries' hosts share, so that it is written once: the session's configuration (Baton's
//! settings over the user's `--zenoh-config`), the inbox every subscriber gets, the publisher outbox the main
//! loop publishes through, and the main loop's waits (a deadline or nothing; SIGINT and SIGTERM). And, for tests of
//! real processes (`baton test --cluster`, the workspace's cluster tests), the cable between an agent and its router
//! that a test pulls out (`cable`).
//!
//! A host here is what `coordinator/src/run` and `agent/src/host.rs` are around their `proto` state machines:
//! it turns samples into inputs, feeds the machine, drains its outputs and re-arms one timer. This crate holds
//! none of a chart's rules — it depends on `proto` only for the settings and limits — and no Rerun: the agent
//! links it.
//!
//! # Rules the hosts keep
//!
//! - A run's messages are handled in the Zenoh callback that delivers them, under the host's lock (`shared`):
//!   decoded, fed to the state machine and what it asks for published before the callback returns, with no hop to
//!   another thread (a hop cost 30–50 µs at each end of a token's round trip on a loaded two-core machine). The main
//!   loop keeps queries, timers, skills' events and signals, and takes the same lock. The rules that come with it
//!   are `shared`'s.
//! - Puts are `CongestionControl::Block` and express, and wait only while their link's queue is full. The one
//!   exception to "published where it was decided" is the coordinator with a journal: what a batch led to is sent
//!   by the journal's writer thread the moment the batch is durable (`Outbox::put` from that thread).
//! - The outbox holds at most `PUBLISHERS_MAX` publishers: keys of finished runs would accumulate otherwise,
//!   and a live key is declared again on its next use.

pub mod cable;
pub mod shared;
pub mod traffic;

pub use shared::{earlier, Shared};

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use anyhow::{anyhow, Context};
use baton_proto::cluster::netconfig::NetConfig;
use baton_proto::limits::RECEIVE_QUEUE_MAX;
use zenoh::handlers::FifoChannel;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::Session;

/// Zenoh's errors as anyhow's: Zenoh's boxed error is not a `std::error::Error` that `?` can turn into one, so
/// every call into Zenoh ends in `.zenoh()?` rather than a `map_err` of its own.
pub trait ZenohResult<T> {
    fn zenoh(self) -> anyhow::Result<T>;
}

impl<T> ZenohResult<T> for zenoh::Result<T> {
    fn zenoh(self) -> anyhow::Result<T> {
        self.map_err(|e| anyhow!("{e}"))
    }
}

/// Publishers a host keeps declared at once.
pub const PUBLISHERS_MAX: usize = 256;

/// The Zenoh configuration of a Baton process: Baton's settings (`net`), on top of the user's own file when one
/// is given (`--zenoh-config`, for TLS endpoints, credentials and the like).
pub fn zenoh_config(net: &NetConfig, file: Option<&Path>) -> anyhow::Result<zenoh::Config> {
    let Some(file) = file else {
        return zenoh::Config::from_json5(&net.json5()).map_err(|e| anyhow!("zenoh configuration: {e}"));
    };
    let mut config =
        zenoh::Config::from_file(file).zenoh().with_context(|| format!("cannot load {}", file.display()))?;
    for (key, value) in net.overrides() {
        config.insert_json5(key, &value).map_err(|e| anyhow!("zenoh configuration `{key}`: {e}"))?;
    }
    Ok(config)
}

/// The identity a process authenticates with, from the user's Zenoh configuration file: its user name
/// (`transport/auth/usrpwd/user`), or else the common name of the TLS certificate it connects with
/// (`transport/link/tls/connect_certificate`, for mutual TLS) — what the router checks; `None` without either.
pub fn zenoh_identity(file: Option<&Path>) -> Option<String> {
    let config = zenoh::Config::from_file(file?).ok()?;
    config_text(&config, "transport/auth/usrpwd/user").or_else(|| certificate_of(&config).map(|(_, cn)| cn))
}

/// The TLS certificate a Zenoh configuration file connects with (`transport/link/tls/connect_certificate`) and the
/// common name it carries; `None` without one (or one that names nobody).
pub fn certificate_identity(file: &Path) -> Option<(std::path::PathBuf, String)> {
    certificate_of(&zenoh::Config::from_file(file).ok()?)
}

fn certificate_of(config: &zenoh::Config) -> Option<(std::path::PathBuf, String)> {
    let path = std::path::PathBuf::from(config_text(config, "transport/link/tls/connect_certificate")?);
    let name = certificate_name(&path)?;
    Some((path, name))
}

/// A string setting of a Zenoh configuration; `None` when it is unset, empty or not a plain string.
fn config_text(config: &zenoh::Config, key: &str) -> Option<String> {
    // A JSON string (`"operator"`), or `null` without one.
    let json = config.get_json(key).ok()?;
    let text = json.trim().strip_prefix('"')?.strip_suffix('"')?;
    (!text.is_empty() && !text.contains(['"', '\\'])).then(|| text.to_string())
}

/// The common name of the first certificate in a PEM file; `None` if the file cannot be read or holds none.
pub fn certificate_name(pem_file: &Path) -> Option<String> {
    let bytes = std::fs::read(pem_file).ok()?;
    let (_, pem) = x509_parser::pem::parse_x509_pem(&bytes).ok()?;
    let cert = pem.parse_x509().ok()?;
    let name = cert.subject().iter_common_name().next()?.as_str().ok()?.trim().to_string();
    (!name.is_empty() && !name.chars().any(char::is_control)).then_some(name)
}

/// Milliseconds since the Unix epoch by this machine's clock: what a journal's header, an agent's trace and the
/// console's "lost since" record.
pub fn unix_ms() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64)
}

/// The inbox of a subscriber or queryable: `RECEIVE_QUEUE_MAX` samples, filled by Zenoh's reader without waiting
/// for the main loop.
pub fn inbox() -> FifoChannel {
    FifoChannel::new(RECEIVE_QUEUE_MAX)
}

/// Why the outbox sent nothing, and what it was told.
#[derive(Debug)]
pub enum Unsent {
    /// The key could not be declared (the session is closing).
    Declare(String),
    /// The put itself failed.
    Put(String),
}

impl std::fmt::Display for Unsent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unsent::Declare(why) | Unsent::Put(why) => f.write_str(why),
        }
    }
}

/// The publishers a host's main loop publishes through, one per key, declared on first use.
pub struct Outbox {
    session: Session,
    publishers: HashMap<String, Publisher<'static>>,
}

impl Outbox {
    pub fn new(session: &Session) -> Outbox {
        Outbox { session: session.clone(), publishers: HashMap::new() }
    }

    /// Publishes `payload` on `key`: in a Zenoh callback, the main loop or the journal's writer thread, blocking while
    /// the link's queue is full (Zenoh's own asynchronous put resolves at once in the same way). Which step failed is
    /// the caller's to weigh: a put that fails is worth a warning (the state machines resend what matters), a key
    /// that cannot be declared may end the process.
    pub fn put(&mut self, key: &str, payload: Vec<u8>) -> Result<(), Unsent> {
        use zenoh::Wait;
        if !self.publishers.contains_key(key) {
            let declared = self.declaring(key).wait();
            self.keep(key.to_string(), declared)?;
        }
        match self.publishers.get(key) {
            Some(p) => p.put(payload).wait().map_err(|e| Unsent::Put(format!("cannot publish on {key}: {e}"))),
            None => Ok(()),
        }
    }

    fn declaring(&self, key: &str) -> zenoh::pubsub::PublisherBuilder<'_, 'static> {
        traffic::publisher(&self.session, key.to_string()).congestion_control(CongestionControl::Block).express(true)
    }

    /// Keeps a declared publisher, the outbox emptied first when it is full.
    fn keep(&mut self, key: String, declared: zenoh::Result<Publisher<'static>>) -> Result<(), Unsent> {
        let declared = declared.map_err(|e| Unsent::Declare(format!("cannot publish on {key}: {e}")))?;
        if self.publishers.len() >= PUBLISHERS_MAX {
            self.publishers.clear();
        }
        self.publishers.insert(key, declared);
        Ok(())
    }

    /// How many publishers are declared now.
    pub fn len(&self) -> usize {
        self.publishers.len()
    }

    pub fn is_empty(&self) -> bool {
        self.publishers.is_empty()
    }
}

/// Waits until `deadline`, or for ever without one: the main loop's timer, re-armed each turn at the state
/// machine's `poll_timeout`.
pub async fn until(deadline: Option<Instant>) {
    match deadline {
        Some(at) => tokio::time::sleep_until(at.into()).await,
        None => std::future::pending().await,
    }
}

/// SIGINT and SIGTERM, as one stream: the main loop's way out.
pub struct Stop {
    interrupt: tokio::signal::unix::Signal,
    terminate: tokio::signal::unix::Signal,
}

impl Stop {
    /// The signal streams, made once (polling them each turn of the loop then costs nothing).
    pub fn new() -> anyhow::Result<Stop> {
        use tokio::signal::unix::{signal, SignalKind};
        Ok(Stop { interrupt: signal(SignalKind::interrupt())?, terminate: signal(SignalKind::terminate())? })
    }

    /// The next SIGINT or SIGTERM, and which.
    pub async fn recv(&mut self) -> Signal {
        tokio::select! {
            _ = self.interrupt.recv() => Signal::Interrupt,
            _ = self.terminate.recv() => Signal::Terminate,
        }
    }
}

/// What a signal asks of a process: SIGINT is a person at the terminal (Ctrl-C), SIGTERM the system taking the
/// process away (`systemctl stop` and `restart`, a reboot, `kill`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Signal {
    Interrupt,
    Terminate,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A session on nothing: no scouting, no listener, no router.
    async fn lone_session() -> Session {
        let mut config = zenoh::Config::default();
        for (k, v) in [("scouting/multicast/enabled", "false"), ("listen/endpoints", "[]"), ("connect/endpoints", "[]")]
        {
            config.insert_json5(k, v).expect("config");
        }
        zenoh::open(config).await.expect("a lone session")
    }

    #[test]
    fn the_identity_is_the_user_name_a_configuration_authenticates_with() {
        let dir = tempfile::tempdir().expect("tmp");
        let with = dir.path().join("operator.json5");
        std::fs::write(&with, r#"{ transport: { auth: { usrpwd: { user: "operator", password: "x" } } } }"#)
            .expect("write");
        let without = dir.path().join("plain.json5");
        std::fs::write(&without, "{ scouting: { multicast: { enabled: false } } }").expect("write");
        assert_eq!(zenoh_identity(Some(&with)).as_deref(), Some("operator"));
        assert_eq!(zenoh_identity(Some(&without)), None);
        assert_eq!(zenoh_identity(None), None);
    }

    /// With mutual TLS and no user name, who sends a command is the common name of the certificate the client
    /// connects with (made here by rcgen, as a CA would issue it); a file that is not a certificate names nobody.
    #[test]
    fn the_identity_is_the_common_name_of_the_clients_tls_certificate() {
        let dir = tempfile::tempdir().expect("tmp");
        let key = rcgen::KeyPair::generate().expect("a key");
        let mut params = rcgen::CertificateParams::new(vec!["localhost".to_string()]).expect("params");
        params.distinguished_name.push(rcgen::DnType::CommonName, "shift-lead-anna");
        params.distinguished_name.push(rcgen::DnType::OrganizationName, "Cell 4");
        let cert = params.self_signed(&key).expect("a certificate");
        let pem = dir.path().join("anna.pem");
        std::fs::write(&pem, cert.pem()).expect("write");
        let config = dir.path().join("anna.json5");
        let text = format!(
            r#"{{ transport: {{ link: {{ tls: {{ connect_certificate: "{}", enable_mtls: true }} }} }} }}"#,
            pem.display()
        );
        std::fs::write(&config, text).expect("write");
        assert_eq!(zenoh_identity(Some(&config)).as_deref(), Some("shift-lead-anna"));
        // A user name, where there is one, is the identity the router checks first.
        let both = dir.path().join("both.json5");
        let text = format!(
            r#"{{ transport: {{ auth: {{ usrpwd: {{ user: "operator", password: "x" }} }}, link: {{ tls: {{ connect_certificate: "{}" }} }} }} }}"#,
            pem.display()
        );
        std::fs::write(&both, text).expect("write");
        assert_eq!(zenoh_identity(Some(&both)).as_deref(), Some("operator"));
        std::fs::write(&pem, "not a certificate").expect("write");
        assert_eq!(zenoh_identity(Some(&config)), None);
        assert_eq!(certificate_name(&dir.path().join("missing.pem")), None);
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn the_outbox_keeps_at_most_its_cap_of_publishers() {
        let session = lone_session().await;
        let mut outbox = Outbox::new(&session);
        for i in 0..PUBLISHERS_MAX + 10 {
            outbox.put(&format!("baton/test/{i}"), vec![1]).expect("a put on a lone session");
            assert!(outbox.len() <= PUBLISHERS_MAX, "{} publishers after {i} keys", outbox.len());
        }
        outbox.put("baton/test/0", vec![2]).expect("again");
        assert!(outbox.len() <= PUBLISHERS_MAX);
    }

    #[test]
    fn the_users_file_is_read_and_batons_settings_apply_over_it() {
        let dir = std::env::temp_dir().join(format!("baton-host-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a folder");
        let file = dir.join("z.json5");
        std::fs::write(&file, r#"{ scouting: { multicast: { enabled: true } }, metadata: { name: "mine" } }"#)
            .expect("write");
        let net = NetConfig::client(&["tcp/127.0.0.1:7447".to_string()], true);
        let config = zenoh_config(&net, Some(&file)).expect("a configuration");
        assert_eq!(config.get_json("scouting/multicast/enabled").expect("scouting"), "false", "Baton's setting wins");
        assert!(config.get_json("metadata").expect("metadata").contains("mine"), "the user's own stays");
        let missing = zenoh_config(&net, Some(&dir.join("absent.json5"))).expect_err("a missing file");
        assert!(format!("{missing:#}").contains("absent.json5"), "{missing:#}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
