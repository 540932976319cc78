//! OPC UA on the agent, with async-opcua's client: the connection a skill opens to a machine's server
//! (`Link`), and the conversions between chart values and OPC UA variants (`convert`). The skills are in
//! `skills` (`opcua_method`).
//!
//! A skill opens its own session to the endpoint it names and closes it when it ends. The session does not
//! reconnect once it is up: a machine that goes away in the middle of a job is a fault of that job, not a wait.

pub mod convert;
pub mod skills;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::str::FromStr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use baton_proto::front::pragma::Param;
use opcua::client::{ClientBuilder, IdentityToken, Session};
use opcua::types::{EndpointDescription, MessageSecurityMode, NodeId, StatusCode, UserTokenPolicy};
use tokio::task::JoinHandle;

/// The agent's OPC UA settings: where its certificates live, and the name it gives servers.
#[derive(Clone, Debug)]
pub struct OpcUa {
    /// The PKI folder: `own/cert.der` and `private/private.pem` (made, self-signed, the first time a secure
    /// endpoint is used), `trusted/` for the servers' certificates, `rejected/` for those not yet trusted.
    pub pki_dir: PathBuf,
    /// The agent's name, in its application URI (`urn:baton-agent:NAME`).
    pub agent: String,
}

/// How a skill reaches its server: the endpoint and its security, from the binding's parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Endpoint {
    pub url: String,
    pub mode: MessageSecurityMode,
    /// The security policy's name as OPC UA spells it (`None`, `Basic256Sha256`, `Aes128_Sha256_RsaOaep`…).
    pub policy: String,
    /// `user := 'name'` with `password := '…'`: a user name token instead of an anonymous session.
    pub user: Option<(String, String)>,
}

impl Endpoint {
    /// `endpoint := 'opc.tcp://…'`, `security := 'None' | 'Sign' | 'SignAndEncrypt'`, `policy := '…'`
    /// (default Basic256Sha256 when signed), `user`, `password`.
    pub fn from_params(params: &BTreeMap<String, Param>, skill: &str) -> Result<Endpoint, String> {
        let text = |k: &str| params.get(k).and_then(Param::as_str);
        let url = text("endpoint")
            .ok_or_else(|| format!("the {skill} skill needs `endpoint := 'opc.tcp://HOST:4840'`"))?
            .to_string();
        if !url.starts_with("opc.tcp://") {
            return Err(format!("`endpoint` must be an opc.tcp:// address, not `{url}`"));
        }
        let mode = match text("security").unwrap_or("None") {
            s if s.eq_ignore_ascii_case("none") => MessageSecurityMode::None,
            s if s.eq_ignore_ascii_case("sign") => MessageSecurityMode::Sign,
            s if s.eq_ignore_ascii_case("signandencrypt") => MessageSecurityMode::SignAndEncrypt,
            other => return Err(format!("`security` must be None, Sign or SignAndEncrypt, not `{other}`")),
        };
        let policy = match (mode, text("policy")) {
            (MessageSecurityMode::None, None) => "None".to_string(),
            (_, None) => "Basic256Sha256".to_string(),
            (_, Some(p)) => p.to_string(),
        };
        let known =
            ["None", "Basic128Rsa15", "Basic256", "Basic256Sha256", "Aes128_Sha256_RsaOaep", "Aes256_Sha256_RsaPss"];
        if !known.contains(&policy.as_str()) {
            return Err(format!("`policy` must be one of {}, not `{policy}`", known.join(", ")));
        }
        if (mode == MessageSecurityMode::None) != (policy == "None") {
            return Err(format!("security {mode:?} does not go with policy {policy}"));
        }
        let user = match (text("user"), text("password")) {
            (Some(u), Some(p)) => Some((u.to_string(), p.to_string())),
            (None, None) => None,
            _ => return Err("`user` and `password` go together".into()),
        };
        Ok(Endpoint { url, mode, policy, user })
    }

    fn description(&self) -> EndpointDescription {
        // The server's endpoint is matched by address, mode and policy; the identity is given apart.
        (self.url.as_str(), self.policy.as_str(), self.mode, UserTokenPolicy::anonymous()).into()
    }

    fn identity(&self) -> IdentityToken {
        match &self.user {
            Some((user, password)) => IdentityToken::new_user_name(user.clone(), password.clone()),
            None => IdentityToken::Anonymous,
        }
    }
}

/// A node named in a parameter (`ns=2;s=Cell.Pick`, `i=2253`).
pub fn node_id(params: &BTreeMap<String, Param>, key: &str) -> Result<Option<NodeId>, String> {
    match params.get(key) {
        None => Ok(None),
        Some(Param::Str(text)) => parse_node(text).map(Some).map_err(|e| format!("`{key}`: {e}")),
        Some(Param::Value(v)) => Err(format!("`{key}` must be a node id such as 'ns=2;s=Cell', not {v}")),
    }
}

pub fn parse_node(text: &str) -> Result<NodeId, String> {
    NodeId::from_str(text.trim()).map_err(|_| format!("`{text}` is not a node id (such as 'ns=2;s=Cell' or 'i=85')"))
}

/// A status code as OPC UA names it.
pub fn status(code: StatusCode) -> String {
    code.to_string()
}

/// An open session and the task that drives it.
pub struct Link {
    pub session: Arc<Session>,
    driver: JoinHandle<StatusCode>,
    pub url: String,
}

/// How often a skill tries again to reach a server that is not up yet, at most.
const RETRY_MAX: Duration = Duration::from_millis(500);

impl OpcUa {
    /// Opens a session to `endpoint`, trying again until `deadline` while the server cannot be reached.
    pub async fn connect(&self, endpoint: &Endpoint, deadline: Instant) -> Result<Link, String> {
        let secure = endpoint.mode != MessageSecurityMode::None;
        let mut client = ClientBuilder::new()
            .application_name("baton-agent")
            .application_uri(format!("urn:baton-agent:{}", self.agent))
            .product_uri("urn:baton-agent")
            .pki_dir(self.pki_dir.clone())
            .create_sample_keypair(secure)
            .trust_server_certs(false)
            // Reconnects are turned off once the session is up (see `Link`); these only cover the first
            // connection, within the deadline.
            .session_retry_limit(-1)
            .session_retry_initial(Duration::from_millis(50))
            .session_retry_max(RETRY_MAX)
            .client()
            .map_err(|errors| format!("the OPC UA client cannot be set up: {}", errors.join("; ")))?;
        let mut wait = Duration::from_millis(20);
        let started = Instant::now();
        let mut last: Option<String> = None;
        let (session, event_loop) = loop {
            let attempt = tokio::time::timeout_at(
                deadline.into(),
                client.connect_to_matching_endpoint(endpoint.description(), endpoint.identity()),
            )
            .await;
            match attempt {
                Ok(Ok(pair)) => break pair,
                Ok(Err(e)) if Instant::now() + wait < deadline => {
                    last = Some(e.to_string());
                    tokio::time::sleep(wait).await;
                    wait = (wait * 2).min(RETRY_MAX);
                }
                Ok(Err(e)) => return Err(format!("cannot reach {}: {}", endpoint.url, status(e.status()))),
                Err(_) => {
                    return Err(match last {
                        Some(last) => format!("cannot reach {}: {last}", endpoint.url),
                        None => format!(
                            "cannot reach {}: no answer in {:.1} s",
                            endpoint.url,
                            started.elapsed().as_secs_f64()
                        ),
                    })
                }
            }
        };
        let mut driver = event_loop.spawn();
        tokio::select! {
            up = tokio::time::timeout_at(deadline.into(), session.wait_for_connection()) => match up {
                Ok(true) => {}
                Ok(false) => {
                    driver.abort();
                    return Err(format!("{} refused the session", endpoint.url));
                }
                Err(_) => {
                    driver.abort();
                    return Err(format!("no session with {} in time", endpoint.url));
                }
            },
            ended = &mut driver => {
                let code = ended.unwrap_or(StatusCode::BadUnexpectedError);
                return Err(format!("no session with {}: {}", endpoint.url, status(code)));
            }
        }
        session.disable_reconnects();
        Ok(Link { session, driver, url: endpoint.url.clone() })
    }
}

impl Link {
    /// Completes when the connection is lost, saying why.
    pub async fn lost(&mut self) -> String {
        let code = (&mut self.driver).await.unwrap_or(StatusCode::BadUnexpectedError);
        format!("lost the connection to {}: {}", self.url, status(code))
    }

    /// Closes the session (bounded: a server that went away does not hold the skill).
    pub async fn close(self) {
        let _ = tokio::time::timeout(Duration::from_secs(2), self.session.disconnect()).await;
        self.driver.abort();
    }
}
