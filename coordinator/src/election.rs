//! `baton run --election etcd://HOST:PORT[,HOST:PORT…]/PREFIX`: coordinators of one run stand in an election on
//! etcd, and only its winner coordinates. The others stand by — each waits in etcd's election (its campaign) — and
//! the first of them wins when the active one's lease ends: it died, it was cut off from etcd, it was stopped.
//!
//! Each coordinator holds a lease of `--lease` seconds, renewed a few times in each TTL. The winner's term is the
//! revision at which etcd created its leadership key: a later winner's is always higher, and every command and
//! coordinator value it sends carries it (`wire::encode_termed`), so that an agent that heard it refuses the
//! deposed one's (`AgentRun::take_term`). A lease that cannot be renewed does not stop a process by itself (a
//! paused or cut-off coordinator does not know it was replaced): so a coordinator stops acting on its own deadline,
//! a third of the TTL before the lease could end in etcd for the standbys — counted from when it sent the last
//! renewal etcd granted, which etcd received later still.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use baton_host::unix_ms;
use tokio::sync::watch;

/// Where the election is held: etcd's client endpoints, the prefix of the run's keys, for `etcds://` the TLS that
/// etcd's client port asks for, and the etcd user this coordinator signs in as where etcd's auth is on.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Election {
    pub endpoints: Vec<String>,
    pub prefix: String,
    pub tls: Option<EtcdTls>,
    pub user: Option<EtcdUser>,
}

/// etcd's client TLS, as etcdctl's `--cacert`, `--cert` and `--key` give it: the CA that signed etcd's server
/// certificate, and this process's own certificate and key where etcd asks for one (`--client-cert-auth`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EtcdTls {
    pub cacert: std::path::PathBuf,
    pub identity: Option<(std::path::PathBuf, std::path::PathBuf)>,
}

/// An etcd user (`etcdctl user add`, with its roles' keys) and the file its password is read from — never the URL,
/// which `ps`, logs and the journal's header show.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EtcdUser {
    pub name: String,
    pub password_file: std::path::PathBuf,
}

const FORM: &str =
    "etcd://HOST:PORT[,HOST:PORT…]/PREFIX or etcds://HOST:PORT[,…]/PREFIX?cacert=FILE[&cert=FILE&key=FILE], \
                    either with [?|&]user=NAME&password-file=FILE";

impl std::str::FromStr for Election {
    type Err = String;

    fn from_str(s: &str) -> Result<Election, String> {
        let (secure, rest) = match (s.strip_prefix("etcd://"), s.strip_prefix("etcds://")) {
            (Some(rest), _) => (false, rest),
            (_, Some(rest)) => (true, rest),
            _ => return Err(format!("`{s}` is not of the form {FORM}")),
        };
        let (rest, query) = rest.split_once('?').unwrap_or((rest, ""));
        let (hosts, prefix) = rest.split_once('/').ok_or_else(|| format!("`{s}` names no PREFIX: {FORM}"))?;
        let prefix = prefix.trim_end_matches('/');
        if prefix.is_empty() {
            return Err(format!("`{s}` names no PREFIX: {FORM}"));
        }
        let scheme = if secure { "https://" } else { "http://" };
        let mut endpoints = Vec::new();
        for host in hosts.split(',') {
            let Some((name, port)) = host.rsplit_once(':') else {
                return Err(format!("`{host}` in `{s}` is not HOST:PORT"));
            };
            if name.is_empty() || port.parse::<u16>().is_err() {
                return Err(format!("`{host}` in `{s}` is not HOST:PORT"));
            }
            endpoints.push(format!("{scheme}{host}"));
        }
        let mut given: Vec<(&str, &str)> = Vec::new();
        for pair in query.split('&').filter(|p| !p.is_empty()) {
            let (name, value) = pair.split_once('=').unwrap_or((pair, ""));
            if !["cacert", "cert", "key", "user", "password-file"].contains(&name) {
                return Err(format!("`{s}`: `{name}` is not one of cacert, cert, key, user and password-file"));
            }
            if value.is_empty() || given.iter().any(|(n, _)| *n == name) {
                return Err(format!("`{s}`: `{name}` takes one value"));
            }
            given.push((name, value));
        }
        let value = |name: &str| given.iter().find(|(n, _)| *n == name).map(|(_, v)| *v);
        let tls = match (secure, ["cacert", "cert", "key"].iter().any(|n| value(n).is_some())) {
            (false, false) => None,
            (false, true) => return Err(format!("`{s}`: TLS files are for etcds://, not etcd://")),
            (true, _) => Some(EtcdTls::of(s, value("cacert"), value("cert"), value("key"))?),
        };
        let user = match (value("user"), value("password-file")) {
            (Some(name), Some(file)) => Some(EtcdUser { name: name.to_string(), password_file: file.into() }),
            (None, None) => None,
            (Some(_), None) => {
                return Err(format!(
                    "`{s}`: user=NAME takes its password from password-file=FILE (never written in the URL)"
                ))
            }
            (None, Some(_)) => return Err(format!("`{s}`: password-file=FILE is for the user=NAME it names")),
        };
        Ok(Election { endpoints, prefix: prefix.to_string(), tls, user })
    }
}

impl EtcdTls {
    fn of(s: &str, cacert: Option<&str>, cert: Option<&str>, key: Option<&str>) -> Result<EtcdTls, String> {
        let cacert =
            cacert.ok_or_else(|| format!("`{s}` names no cacert=FILE, the CA that signed etcd's certificate"))?;
        let identity = match (cert, key) {
            (Some(cert), Some(key)) => Some((cert.into(), key.into())),
            (None, None) => None,
            _ => return Err(format!("`{s}`: cert=FILE and key=FILE go together")),
        };
        Ok(EtcdTls { cacert: cacert.into(), identity })
    }

    /// etcd-client's TLS options, from the files as they are now (a certificate renewed since the last connection
    /// is the one used).
    fn options(&self) -> anyhow::Result<etcd_client::TlsOptions> {
        let read = |path: &std::path::Path, what: &str| {
            std::fs::read(path).with_context(|| format!("cannot read {what} {}", path.display()))
        };
        let ca = etcd_client::Certificate::from_pem(read(&self.cacert, "etcd's CA certificate")?);
        let mut tls = etcd_client::TlsOptions::new().ca_certificate(ca);
        if let Some((cert, key)) = &self.identity {
            let identity =
                etcd_client::Identity::from_pem(read(cert, "the certificate for etcd")?, read(key, "its key")?);
            tls = tls.identity(identity);
        }
        Ok(tls)
    }
}

impl std::fmt::Display for Election {
    /// As `--election` takes it: `etcd://HOST:PORT[,HOST:PORT…]/PREFIX`, or `etcds://…` with its TLS files, and
    /// the user and its password's file.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let hosts: Vec<&str> =
            self.endpoints.iter().map(|e| e.trim_start_matches("http://").trim_start_matches("https://")).collect();
        let mut query = Vec::new();
        if let Some(tls) = &self.tls {
            query.push(format!("cacert={}", tls.cacert.display()));
            if let Some((cert, key)) = &tls.identity {
                query.push(format!("cert={}&key={}", cert.display(), key.display()));
            }
        }
        if let Some(user) = &self.user {
            query.push(format!("user={}&password-file={}", user.name, user.password_file.display()));
        }
        let scheme = if self.tls.is_some() { "etcds" } else { "etcd" };
        write!(f, "{scheme}://{}/{}", hosts.join(","), self.prefix)?;
        if !query.is_empty() {
            write!(f, "?{}", query.join("&"))?;
        }
        Ok(())
    }
}

impl Election {
    /// The election's name in etcd (its candidates' keys are under it).
    fn name(&self) -> String {
        format!("{}/coordinator", self.prefix)
    }
}

/// A coordinator in the election, as its candidacy's value in etcd says it, and its term (the revision of its
/// candidacy: the lowest is the active coordinator's).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Candidate {
    pub name: String,
    #[serde(default)]
    pub term: u64,
    /// Since when it stands by, or, once it won, since when it is active (Unix ms).
    pub since_unix_ms: u64,
}

impl Candidate {
    /// The candidacy a key of the election holds; its term is the key's creation revision. A value that is not a
    /// candidacy's (written by another tool) is shown as it is.
    fn of(kv: &etcd_client::KeyValue) -> Candidate {
        let mut c = serde_json::from_slice::<Candidate>(kv.value()).unwrap_or_else(|_| Candidate {
            name: String::from_utf8_lossy(kv.value()).into_owned(),
            term: 0,
            since_unix_ms: 0,
        });
        c.term = kv.create_revision().max(0) as u64;
        c
    }
}

/// Who stands in the election now, for `baton status`: the active coordinator, then the standbys in the order they
/// would win. Empty if nobody stands.
pub async fn candidates(election: &Election) -> anyhow::Result<Vec<Candidate>> {
    Follower::new(election.clone()).read().await
}

/// Reads an election's candidates again and again (the console's), on one connection to etcd while it serves.
pub struct Follower {
    election: Election,
    client: Option<etcd_client::Client>,
}

impl Follower {
    pub fn new(election: Election) -> Follower {
        Follower { election, client: None }
    }

    /// The candidates now: the active coordinator first, then the standbys in the order they would win.
    pub async fn read(&mut self) -> anyhow::Result<Vec<Candidate>> {
        let shown = self.election.endpoints.join(",");
        let read = tokio::time::timeout(Duration::from_secs(5), self.ask()).await;
        let found = match read {
            Ok(Ok(found)) => found,
            Ok(Err(e)) => {
                self.client = None;
                return Err(e).with_context(|| format!("cannot read the election from etcd at {shown}"));
            }
            Err(_) => {
                self.client = None;
                bail!("etcd at {shown} did not answer within 5 s");
            }
        };
        let mut kvs: Vec<&etcd_client::KeyValue> = found.kvs().iter().collect();
        kvs.sort_by_key(|kv| kv.create_revision());
        Ok(kvs.into_iter().map(Candidate::of).collect())
    }

    /// The candidacies' keys, asked again past a member that is down (the client balances over all of them).
    async fn ask(&mut self) -> Result<etcd_client::GetResponse, etcd_client::Error> {
        let client = match &mut self.client {
            Some(client) => client,
            None => {
                let options = etcd_client::ConnectOptions::new().with_connect_timeout(Duration::from_secs(2));
                let options =
                    with_tls(&self.election, options).map_err(|e| etcd_client::Error::InvalidArgs(format!("{e:#}")))?;
                self.client.insert(connect(&self.election, &self.election.endpoints, options, true).await?)
            }
        };
        let prefix = format!("{}/", self.election.name());
        loop {
            match client.get(prefix.as_str(), Some(etcd_client::GetOptions::new().with_prefix())).await {
                Err(e) if !refused(&e) => tokio::time::sleep(RETRY).await,
                answer => return answer,
            }
        }
    }
}

/// An election won: the term, and the reason the coordinator must stop acting, once it must.
pub struct Won {
    pub term: u64,
    /// `Some(why)` once the lease is lost, or about to be for the standbys.
    pub lost: watch::Receiver<Option<String>>,
    /// True until then: turned false by the renewing task at the moment it finds the lease lost, for the journal's
    /// writer to send nothing more without waiting for the main loop.
    pub acting: Arc<AtomicBool>,
    renewing: tokio::task::JoinHandle<()>,
    client: etcd_client::Client,
    lease: i64,
    /// The leadership key etcd made for this win, and how the win is lost (`fence`).
    key: Vec<u8>,
    lose: Arc<Lose>,
    lease_s: u64,
}

/// What a store written by the winner needs to write only while it holds the election (`Won::fence`): its
/// leadership key, which exists with that creation revision (the term) only as long as the lease does.
#[derive(Clone)]
pub struct Fence {
    pub key: Vec<u8>,
    pub term: u64,
    /// How long one request to etcd may take before it is asked again (of another member): a sixth of the lease.
    pub patience: Duration,
    pub lease_s: u64,
    lose: Arc<Lose>,
}

impl Fence {
    /// Whether this coordinator still acts (its lease not lost, nor about to be).
    pub fn acting(&self) -> bool {
        self.lose.acting.load(Ordering::SeqCst)
    }

    /// Stops this coordinator's acting at once, for `why` (etcd refused a write: another coordinator holds the
    /// election): as a lost lease does.
    pub fn lose(&self, why: String) {
        self.lose.because(why);
    }
}

impl Won {
    /// The fence of this win, for the journal in etcd.
    pub fn fence(&self) -> Fence {
        let patience = Duration::from_millis(self.lease_s * 1000 / 6);
        Fence { key: self.key.clone(), term: self.term, patience, lease_s: self.lease_s, lose: Arc::clone(&self.lose) }
    }

    /// Gives the election up at once (the lease revoked), for a standby to win without waiting for the lease to
    /// end: the run is over, or left as it stands by a SIGTERM. Best effort, within a second.
    pub async fn resign(mut self) {
        self.renewing.abort();
        // Asked again past a member that is down, as every request is.
        let revoke = async {
            loop {
                match self.client.lease_revoke(self.lease).await {
                    Err(e) if !refused(&e) => tokio::time::sleep(RETRY).await,
                    done => return done.map(drop),
                }
            }
        };
        match tokio::time::timeout(Duration::from_secs(1), revoke).await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => eprintln!("baton: warning: could not give the election up (its lease ends by itself): {e}"),
            Err(_) => {
                eprintln!("baton: warning: etcd did not take the election back within 1 s (its lease ends by itself)")
            }
        }
    }
}

impl Drop for Won {
    fn drop(&mut self) {
        self.renewing.abort();
    }
}

/// How a coordinator with a lease of `lease_s` seconds talks to etcd: a member without a leader refuses (its answer
/// could be stale), and a connection that stops answering is found within a third of the lease.
pub(crate) fn connect_options(election: &Election, lease_s: u64) -> anyhow::Result<etcd_client::ConnectOptions> {
    let options = etcd_client::ConnectOptions::new()
        .with_connect_timeout(Duration::from_secs(lease_s))
        .with_keep_alive(Duration::from_millis(lease_s * 1000 / 3), Duration::from_millis(lease_s * 1000 / 3))
        .with_require_leader(true);
    with_tls(election, options)
}

/// `options` with the election's TLS, for `etcds://`, and a token signed in again when etcd says it expired.
fn with_tls(election: &Election, options: etcd_client::ConnectOptions) -> anyhow::Result<etcd_client::ConnectOptions> {
    let options = options.with_auto_token_refresh(true);
    Ok(match &election.tls {
        Some(tls) => options.with_tls(tls.options()?),
        None => options,
    })
}

/// A client of the election's etcd at `endpoints`, signed in as the election's user where it names one (its
/// password read from its file now). A sign-in etcd refuses (a wrong password, a user unknown, auth not enabled)
/// is an error at once; an etcd that does not answer is asked again until it does (said once) where `wait`, a
/// caller that must not wait that long bounding it, and is the caller's error otherwise.
pub(crate) async fn connect(
    election: &Election,
    endpoints: &[String],
    options: etcd_client::ConnectOptions,
    wait: bool,
) -> Result<etcd_client::Client, etcd_client::Error> {
    let mut client = etcd_client::Client::connect(endpoints, Some(options)).await?;
    let Some(user) = &election.user else { return Ok(client) };
    let password = std::fs::read_to_string(&user.password_file).map_err(|e| {
        etcd_client::Error::InvalidArgs(format!(
            "cannot read the password of etcd user `{}` from {}: {e}",
            user.name,
            user.password_file.display()
        ))
    })?;
    let password = password.trim_end_matches(['\n', '\r']).to_string();
    let mut said = false;
    loop {
        match client.update_user(Some((user.name.clone(), password.clone()))).await {
            Ok(()) => return Ok(client),
            Err(etcd_client::Error::GRpcStatus(s)) if !unanswered(&s) => {
                return Err(etcd_client::Error::InvalidArgs(format!(
                    "etcd refused the sign-in of user `{}` (password from {}): {}",
                    user.name,
                    user.password_file.display(),
                    s.message()
                )))
            }
            Err(e) if !wait => return Err(e),
            Err(e) => {
                if !said {
                    eprintln!(
                        "baton: etcd at {} does not answer ({e}): waiting to sign in as `{}`",
                        endpoints.join(","),
                        user.name
                    );
                    said = true;
                }
                tokio::time::sleep(RETRY).await;
            }
        }
    }
}

/// Whether etcd's answer says only that no member answered (down, unreachable, out of time): asked again.
fn unanswered(status: &tonic::Status) -> bool {
    use tonic::Code;
    matches!(status.code(), Code::Unavailable | Code::DeadlineExceeded | Code::Cancelled | Code::Unknown)
}

/// Joins the election as `candidate` with a lease of `lease_s` seconds and waits until it wins: standing by,
/// meanwhile, behind the coordinator that holds it (said once, unless `quiet`).
pub async fn win(election: &Election, lease_s: u64, candidate: &str, quiet: bool) -> anyhow::Result<Won> {
    let shown = election.endpoints.join(",");
    let options = connect_options(election, lease_s)?;
    let mut client = connect(election, &election.endpoints, options.clone(), true)
        .await
        .with_context(|| format!("cannot reach etcd at {shown}"))?;
    loop {
        let Candidacy { lease, mut lost, acting, renewing, lose } =
            stand(&mut client, &options, election, lease_s).await?;
        if !quiet {
            if let Ok(now) = client.leader(election.name()).await {
                if let Some(active) = now.kv().map(Candidate::of) {
                    eprintln!(
                        "baton: standing by: {} coordinates (term {}); taking over when its lease of etcd ends",
                        active.name, active.term
                    );
                }
            }
        }
        let standing = serde_json::to_string(&Candidate { name: candidate.into(), term: 0, since_unix_ms: unix_ms() })?;
        // Campaigning again with the same lease is the same candidacy (etcd keys it by the lease).
        let won = loop {
            let campaign = client.campaign(election.name(), standing.as_str(), lease);
            tokio::select! {
                won = campaign => match won {
                    Ok(won) => break Some(won),
                    Err(e) if !refused(&e) => tokio::time::sleep(RETRY).await,
                    Err(e) => return Err(e).with_context(|| format!("the election on etcd at {shown} failed")),
                },
                why = async { lost.wait_for(Option::is_some).await.map(|w| w.clone()) } => {
                    // A standby acts on nothing: its candidacy lapsed (etcd unreachable, or electing a leader of
                    // its own), and it stands again.
                    let why = why.ok().flatten().unwrap_or_default();
                    eprintln!("baton: warning: standing by, its candidacy lapsed ({why}): standing again");
                    renewing.abort();
                    break None;
                }
            }
        };
        let Some(won) = won else { continue };
        let key = won.leader().ok_or_else(|| anyhow!("etcd at {shown} named no leadership key"))?;
        let term = u64::try_from(key.rev()).map_err(|_| anyhow!("etcd gave a negative revision"))?;
        // The candidacy now says since when it is active (`baton status --election`).
        let active = serde_json::to_string(&Candidate { name: candidate.into(), term, since_unix_ms: unix_ms() })?;
        let proclaim = etcd_client::ProclaimOptions::new().with_leader(key.clone());
        if let Err(e) = client.proclaim(active, Some(proclaim)).await {
            eprintln!("baton: warning: could not tell etcd since when this coordinator is active: {e}");
        }
        let key = key.key().to_vec();
        return Ok(Won { term, lost, acting, renewing, client, lease, key, lose, lease_s });
    }
}

/// A lease granted, and renewed by a task of its own until it is lost (`lost`, `acting`).
struct Candidacy {
    lease: i64,
    lost: watch::Receiver<Option<String>>,
    acting: Arc<AtomicBool>,
    renewing: tokio::task::JoinHandle<()>,
    lose: Arc<Lose>,
}

/// A candidacy: a lease of `lease_s` seconds granted, and renewed from now on by a task of its own.
async fn stand(
    client: &mut etcd_client::Client,
    options: &etcd_client::ConnectOptions,
    election: &Election,
    lease_s: u64,
) -> anyhow::Result<Candidacy> {
    let shown = election.endpoints.join(",");
    // A request may go to a member that is down (the client balances over all of them): it is asked again.
    // Without a quorum etcd grants nothing: a candidate waits for it (and says so once).
    let (mut said, mut last) = (false, String::from("no answer"));
    let grant = loop {
        let asked = tokio::time::timeout(Duration::from_secs(lease_s), async {
            loop {
                match client.lease_grant(lease_s as i64, None).await {
                    Ok(grant) => return Ok(grant),
                    Err(e) if !refused(&e) => {
                        last = e.to_string();
                        tokio::time::sleep(RETRY).await;
                    }
                    Err(e) => return Err(e),
                }
            }
        });
        match asked.await {
            Ok(granted) => break granted.with_context(|| format!("etcd at {shown} granted no lease"))?,
            Err(_) if !said => {
                // Over TLS, a handshake etcd refused looks the same as a member down: say where else to look.
                let tls = match &election.tls {
                    Some(tls) if tls.identity.is_none() => {
                        "; over etcds://, does etcd require a client certificate (cert=FILE&key=FILE)?"
                    }
                    Some(_) => "; over etcds://, did etcd's CA sign this certificate, and cacert sign etcd's?",
                    None => "",
                };
                eprintln!(
                    "baton: etcd at {shown} grants no lease (unreachable, or without a quorum: {last}{tls}): waiting \
                     for it"
                );
                said = true;
            }
            Err(_) => {}
        }
    };
    let (lease, granted) = (grant.id(), grant.ttl());
    if granted as u64 != lease_s {
        bail!("etcd at {shown} granted a lease of {granted} s, not the {lease_s} s asked for: give --lease {granted}");
    }
    let (tell, lost) = watch::channel(None);
    let acting = Arc::new(AtomicBool::new(true));
    let lose = Arc::new(Lose { acting: Arc::clone(&acting), tell });
    let renewing = tokio::spawn(renew(election.clone(), options.clone(), lease, lease_s, Arc::clone(&lose)));
    Ok(Candidacy { lease, lost, acting, renewing, lose })
}

/// How a candidacy is lost: `acting` turns false first, then the reason is told.
struct Lose {
    acting: Arc<AtomicBool>,
    tell: watch::Sender<Option<String>>,
}

impl Lose {
    fn because(&self, why: String) {
        self.acting.store(false, Ordering::SeqCst);
        let _ = self.tell.send(Some(why));
    }
}

/// How long to wait before asking etcd again after a member did not answer.
pub(crate) const RETRY: Duration = Duration::from_millis(100);

/// Whether etcd refused a request for what it is (bad arguments, no permission), rather than a member being out
/// of reach (down, cut off, reset), so that another member may answer the same request.
pub(crate) fn refused(e: &etcd_client::Error) -> bool {
    use tonic::Code;
    match e {
        etcd_client::Error::GRpcStatus(s) => matches!(
            s.code(),
            Code::InvalidArgument | Code::PermissionDenied | Code::Unauthenticated | Code::NotFound | Code::OutOfRange
        ),
        etcd_client::Error::InvalidArgs(_) | etcd_client::Error::InvalidUri(_) => true,
        _ => false,
    }
}

/// A member's client being made (and signed in) for the renewals.
type SigningIn = tokio::task::JoinHandle<Result<etcd_client::Client, etcd_client::Error>>;

/// Renews `lease` several times in each TTL until it is lost: etcd says it expired, or no renewal was granted in
/// time for this process to stop acting before it can expire for others. Says why on `tell`, once. Renewals go to
/// one member at a time; one that does not answer in a sixth of the TTL is left for the next.
async fn renew(election: Election, options: etcd_client::ConnectOptions, lease: i64, lease_s: u64, lose: Arc<Lose>) {
    let ttl = Duration::from_secs(lease_s);
    let every = ttl / 6;
    // The lease is this process's until a third of the TTL before it could end: etcd counts the TTL from when it
    // received the renewal, later than it was sent.
    let mut own_until = Instant::now() + ttl - ttl / 3;
    let mut last_error = String::from("no answer");
    let mut member = 0;
    let mut stream = None;
    // A client of each member, signed in once: where etcd's auth is on, a sign-in costs etcd a bcrypt of the
    // password (tens of ms, more on a busy machine), which each renewal must not pay again.
    let mut clients: Vec<Option<etcd_client::Client>> = vec![None; election.endpoints.len()];
    let mut signing: Vec<Option<SigningIn>> = election.endpoints.iter().map(|_| None).collect();
    loop {
        let sent = Instant::now();
        let attempt = async {
            if stream.is_none() {
                if clients[member].is_none() {
                    // A task of its own, so that an attempt's deadline does not cut the sign-in short: the next
                    // attempt on this member waits for the same one. A member that does not answer is not waited
                    // for (`wait` false): it is left for the next (below).
                    let signing_in = signing[member].get_or_insert_with(|| {
                        let (election, options) = (election.clone(), options.clone());
                        let endpoint = [election.endpoints[member].clone()];
                        tokio::spawn(async move { connect(&election, &endpoint, options, false).await })
                    });
                    let signed = signing_in.await;
                    signing[member] = None;
                    let signed = signed.map_err(|e| etcd_client::Error::LeaseKeepAliveError(e.to_string()))?;
                    clients[member] = Some(signed?);
                }
                let mut client = clients[member].clone().expect("signed in above");
                stream = Some(client.lease_keep_alive(lease).await?);
            }
            let (keeper, answers) = stream.as_mut().expect("opened above");
            keeper.keep_alive().await?;
            answers.message().await
        };
        // One try may hang on a member that lost its quorum: the next goes again, perhaps to another member.
        let answered = tokio::time::timeout_at(own_until.min(sent + every).into(), attempt).await;
        if !matches!(answered, Ok(Ok(Some(_)))) {
            member = (member + 1) % election.endpoints.len();
        }
        match answered {
            Ok(Ok(Some(answer))) if answer.ttl() > 0 => {
                own_until = sent + Duration::from_secs(answer.ttl() as u64) - ttl / 3;
            }
            Ok(Ok(Some(_))) => {
                lose.because("etcd says its lease expired: a standby may have taken over".into());
                return;
            }
            Ok(Ok(None)) => {
                last_error = "etcd closed the renewal stream".into();
                stream = None;
            }
            Ok(Err(e)) => {
                last_error = e.to_string();
                stream = None;
            }
            Err(_) => {
                last_error = format!("no answer within {} ms", every.as_millis());
                stream = None;
            }
        }
        if Instant::now() >= own_until {
            lose.because(format!(
                "no renewal of its lease was granted by etcd in time ({last_error}): stopping {} ms before the lease \
                 of {lease_s} s can end for the standbys",
                (ttl / 3).as_millis()
            ));
            return;
        }
        tokio::time::sleep_until((sent + every).min(own_until).into()).await;
    }
}

#[cfg(test)]
mod tests {
    use super::{connect, connect_options, refused, Election, EtcdUser};
    use std::time::Duration;

    #[test]
    fn an_election_is_named_by_etcds_endpoints_and_a_prefix() {
        let e: Election = "etcd://127.0.0.1:2379,10.0.0.2:2379/cell1".parse().expect("valid");
        assert_eq!(e.endpoints, ["http://127.0.0.1:2379", "http://10.0.0.2:2379"]);
        assert_eq!(e.to_string(), "etcd://127.0.0.1:2379,10.0.0.2:2379/cell1", "written as it is given");
        assert_eq!(e.prefix, "cell1");
        assert_eq!(e.name(), "cell1/coordinator");
        for bad in ["127.0.0.1:2379/cell1", "etcd://127.0.0.1:2379", "etcd://127.0.0.1:2379/", "etcd://host/cell1"] {
            assert!(bad.parse::<Election>().is_err(), "{bad} taken");
        }
    }

    #[test]
    fn etcds_names_the_tls_files_as_etcdctl_does() {
        let given = "etcds://10.0.0.1:2379,10.0.0.2:2379/cell1?cacert=/etc/baton/ca.pem&cert=/etc/baton/c1.pem&key=/k";
        let e: Election = given.parse().expect("valid");
        assert_eq!(e.endpoints, ["https://10.0.0.1:2379", "https://10.0.0.2:2379"], "etcd's client port over TLS");
        let tls = e.tls.as_ref().expect("TLS");
        assert_eq!(tls.cacert, std::path::Path::new("/etc/baton/ca.pem"));
        assert_eq!(
            tls.identity.as_ref().map(|(c, k)| (c.to_str(), k.to_str())),
            Some((Some("/etc/baton/c1.pem"), Some("/k")))
        );
        assert_eq!(e.to_string(), given, "written as it is given, so that a journal's place compares equal");
        let ca_only: Election =
            "etcds://h:2379/cell1?cacert=/ca.pem".parse().expect("a CA alone: no client certificate");
        assert_eq!(ca_only.tls.and_then(|t| t.identity), None);
        refused_saying(&[
            ("etcds://h:2379/cell1", "cacert"),
            ("etcds://h:2379/cell1?cacert=/ca.pem&cert=/c.pem", "go together"),
            ("etcds://h:2379/cell1?cacert=/ca.pem&pasword-file=/p", "not one of"),
            ("etcds://h:2379/cell1?cacert=", "one value"),
            ("etcds://h:2379/cell1?cacert=/a.pem&cacert=/b.pem", "one value"),
            ("etcd://h:2379/cell1?cacert=/ca.pem", "etcds://"),
        ]);
    }

    /// Each place is refused, its message saying what is wrong.
    fn refused_saying(cases: &[(&str, &str)]) {
        for (bad, says) in cases {
            let e = bad.parse::<Election>().expect_err(bad);
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    /// A coordinator that starts before its etcd does waits for it, signed in or not: a sign-in that finds nobody
    /// is asked again, never taken for a refusal (which would end the coordinator under systemd).
    #[tokio::test]
    async fn a_sign_in_that_finds_no_etcd_waits_for_it() {
        let dir = tempfile::tempdir().expect("temp dir");
        let file = dir.path().join("password");
        std::fs::write(&file, "secret\n").expect("password file");
        let closed = std::net::TcpListener::bind("127.0.0.1:0").expect("a free port");
        let port = closed.local_addr().expect("its address").port();
        drop(closed);
        let e: Election = format!("etcd://127.0.0.1:{port}/cell1?user=cell1&password-file={}", file.display())
            .parse()
            .expect("valid");
        let options = connect_options(&e, 1).expect("options");
        let waited = tokio::time::timeout(Duration::from_millis(1500), connect(&e, &e.endpoints, options, true)).await;
        assert!(waited.is_err(), "still asking after 1.5 s: {:?}", waited.map(|r| r.map(|_| ())));
        // A renewal asks one member at a time, and leaves one that does not answer for the next: not a refusal.
        let once = connect(&e, &e.endpoints, connect_options(&e, 1).expect("options"), false).await;
        assert!(once.as_ref().is_err_and(|err| !refused(err)), "{:?}", once.map(|_| ()));
        let missing =
            Election { user: Some(EtcdUser { name: "cell1".into(), password_file: dir.path().join("none") }), ..e };
        let unread = connect(&missing, &missing.endpoints, connect_options(&missing, 1).expect("options"), true).await;
        let said = unread.map(|_| ()).expect_err("no password file").to_string();
        assert!(said.contains("cannot read the password of etcd user `cell1`"), "{said}");
    }

    /// etcd's users, as etcdctl's `--user NAME` gives one, over either scheme; its password from a file only.
    #[test]
    fn an_etcd_user_takes_its_password_from_a_file_never_the_url() {
        let given = "etcd://h:2379/cell1?user=cell1&password-file=/etc/baton/etcd-password";
        let e: Election = given.parse().expect("valid");
        let user = e.user.as_ref().expect("a user");
        assert_eq!((user.name.as_str(), user.password_file.to_str()), ("cell1", Some("/etc/baton/etcd-password")));
        assert_eq!(e.tls, None);
        assert_eq!(e.to_string(), given, "written as it is given");
        let both = "etcds://h:2379/cell1?cacert=/ca.pem&cert=/c.pem&key=/k&user=cell1&password-file=/p";
        let e: Election = both.parse().expect("TLS and a user");
        assert!(e.tls.is_some() && e.user.is_some());
        assert_eq!(e.to_string(), both);
        refused_saying(&[
            ("etcd://h:2379/cell1?user=cell1", "password-file=FILE"),
            ("etcd://h:2379/cell1?user=cell1&password=secret", "not one of"),
            ("etcd://h:2379/cell1?password-file=/p", "user=NAME"),
            ("etcd://h:2379/cell1?user=&password-file=/p", "one value"),
        ]);
    }
}
