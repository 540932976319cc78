//! A ROS 2 node over the agent's Zenoh session, speaking rmw_zenoh — or the keys of zenoh-bridge-ros2dds, for
//! robots on DDS (`Via`): it announces itself in the ROS graph, waits for a server's liveliness token, calls
//! services (a query with the CDR request and the attachment), and subscribes to topics. A ROS 2 action is built
//! from these, as rmw_zenoh and the bridge build it: three services and a feedback topic (see `skills`).

use baton_proto::exec::trace::TraceEvent;
use std::sync::atomic::{AtomicI64, AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use baton_ros2::interfaces::{ActionType, Interfaces, ServiceType, TopicType, WireType};
use tokio::sync::Mutex;
use zenoh::liveliness::LivelinessToken;
use zenoh::qos::CongestionControl;
use zenoh::query::{ConsolidationMode, QueryTarget};
use zenoh::sample::SampleKind;
use zenoh::Session;

use super::rmw_keys::{self as keys, Kind, NodeId, Via};

/// A call whose server takes this long to answer is given up: a service answers at once, and an action's
/// result is waited for through its own step time in the chart. (rmw_zenoh waits for ever.)
const CALL_TIMEOUT_MAX: Duration = Duration::from_secs(7 * 24 * 3600);
/// How long a call no server took is sent again (`Node::call`), and the first pause before it is.
const UNMATCHED_RETRY: Duration = Duration::from_secs(2);
const FIRST_PAUSE: Duration = Duration::from_millis(10);

/// The agent's ROS 2 side: its interface types, its domain, how it reaches the graph, and its node (made on
/// first use).
pub struct Ros2 {
    pub lib: Arc<Interfaces>,
    pub domain: u32,
    pub via: Via,
    node_name: String,
    agent: String,
    node: Mutex<Option<Arc<Node>>>,
}

impl Ros2 {
    pub fn new(lib: Arc<Interfaces>, domain: u32, via: Via, agent: &str) -> Ros2 {
        let node_name = format!("baton_{}", agent.replace('-', "_"));
        Ros2 { lib, domain, via, node_name, agent: agent.to_string(), node: Mutex::new(None) }
    }

    /// The agent's node on `session`, announced in the ROS graph the first time it is needed.
    pub async fn node(&self, session: &Session) -> Result<Arc<Node>, String> {
        let mut slot = self.node.lock().await;
        if let Some(n) = slot.as_ref().filter(|n| n.session.zid() == session.zid()) {
            return Ok(Arc::clone(n));
        }
        let zid = session.zid().to_string();
        let id = NodeId {
            domain: self.domain,
            zid: zid.clone(),
            id: 0,
            namespace: "/".into(),
            name: self.node_name.clone(),
        };
        // A bridge announces endpoints, not nodes.
        let token = match self.via {
            Via::RmwZenoh => Some(announce(session, id.token(), "the ROS 2 node").await?),
            Via::Bridge => None,
        };
        let node = Arc::new(Node {
            session: session.clone(),
            id,
            via: self.via,
            agent: self.agent.clone(),
            next_entity: AtomicU32::new(1),
            next_sequence: AtomicI64::new(1),
            _token: token,
        });
        *slot = Some(Arc::clone(&node));
        Ok(node)
    }
}

pub struct Node {
    session: Session,
    id: NodeId,
    via: Via,
    /// The agent's name, for its trace.
    agent: String,
    next_entity: AtomicU32,
    next_sequence: AtomicI64,
    _token: Option<LivelinessToken>,
}

/// The source time of a request or a publication, as rmw_zenoh's attachment carries it.
fn now_ns() -> i64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as i64)
}

pub type Subscription = zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>;

/// A publisher of the node: its messages numbered from 1, with their source time and the publisher's GID.
pub struct TopicPublisher {
    endpoint: Endpoint,
    publisher: zenoh::pubsub::Publisher<'static>,
    sequence: i64,
}

impl TopicPublisher {
    /// Publishes one message, its CDR bytes.
    pub async fn put(&mut self, bytes: Vec<u8>) -> Result<(), String> {
        self.sequence += 1;
        self.publisher
            .put(bytes)
            .attachment(keys::attachment(self.sequence, now_ns(), &self.endpoint.gid))
            .await
            .map_err(|e| format!("cannot publish: {e}"))
    }
}

/// An endpoint of the node (a client, a subscription), announced while it lives.
pub struct Endpoint {
    pub gid: [u8; 16],
    _token: Option<LivelinessToken>,
}

/// Declares a liveliness token; `what` says what it announces, for the error.
async fn announce(session: &Session, key: String, what: &str) -> Result<LivelinessToken, String> {
    baton_host::traffic::token(session, key).await.map_err(|e| format!("cannot announce {what}: {e}"))
}

/// Whether `name` is one of an action's services or topics (`<action>/_action/send_goal`…), which a bridge
/// announces with the action as a whole.
fn is_action_part(name: &str) -> bool {
    name.contains("/_action/")
}

impl Node {
    pub fn domain(&self) -> u32 {
        self.id.domain
    }

    pub fn via(&self) -> Via {
        self.via
    }

    /// Where the node's peers are, for messages: `ROS domain 3`, or behind a bridge.
    pub fn graph(&self) -> String {
        match self.via {
            Via::RmwZenoh => format!("ROS domain {}", self.id.domain),
            Via::Bridge => "the zenoh-bridge-ros2dds graph".to_string(),
        }
    }

    pub fn session(&self) -> &Session {
        &self.session
    }

    /// Declares an endpoint's liveliness token, so that `ros2 node info` and the like see it.
    pub async fn endpoint(&self, kind: Kind, name: &str, wire: &WireType, qos: &str) -> Result<Endpoint, String> {
        let entity = self.next_entity.fetch_add(1, Ordering::Relaxed);
        let key = match self.via {
            Via::RmwZenoh => Some(self.id.endpoint_token(entity, kind, name, wire, qos)),
            Via::Bridge if is_action_part(name) => None,
            Via::Bridge => Some(keys::bridge_token(&self.id.zid, kind, name, &keys::ros_type(&wire.dds_name))),
        };
        let token = match key {
            Some(key) => Some(announce(&self.session, key, &format!("the ROS 2 endpoint for {name}")).await?),
            None => None,
        };
        // A GID unique to this endpoint: the session's id with the entity's number.
        let mut gid = [0u8; 16];
        let zid = self.session.zid().to_le_bytes();
        gid[..zid.len().min(12)].copy_from_slice(&zid[..zid.len().min(12)]);
        gid[12..].copy_from_slice(&entity.to_le_bytes());
        Ok(Endpoint { gid, _token: token })
    }

    /// Waits until a server of `kind` for `name` with type `wire` is in the graph, until `deadline`. A server of
    /// another type is named in the error: it would never answer. With `any_hash`, a server of the same type
    /// name whose hash differs is taken, and its type returned: for standard types whose definition cannot
    /// differ, where implementations disagree on the hash.
    pub async fn wait_for(
        &self,
        kind: Kind,
        name: &str,
        wire: &WireType,
        any_hash: bool,
        deadline: Instant,
    ) -> Result<WireType, String> {
        let pattern = keys::servers(self.via, self.id.domain, kind, name);
        let sub = baton_host::traffic::liveliness_subscriber(&self.session, pattern)
            .history(true)
            .await
            .map_err(|e| format!("cannot watch the ROS graph: {e}"))?;
        let mut other: Option<WireType> = None;
        let what = match kind {
            Kind::Publisher => "publisher",
            _ => "server",
        };
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let sample = match tokio::time::timeout(left, sub.recv_async()).await {
                Ok(Ok(s)) => s,
                Ok(Err(_)) => return Err("the Zenoh session closed".to_string()),
                Err(_) => {
                    let waited = "within the timeout";
                    return Err(match other {
                        Some(t) => format!(
                            "the {what} of {name} on {} has type {}, not {}: the two sides were built from different definitions or ROS 2 distributions",
                            self.graph(), keys::describe(self.via, &t), keys::describe(self.via, wire)
                        ),
                        None => format!("no {what} of {name} appeared on {} {waited}", self.graph()),
                    });
                }
            };
            if sample.kind() != SampleKind::Put {
                continue;
            }
            match keys::announced_type(self.via, sample.key_expr().as_str()) {
                // Through a bridge the token holds no hash: the client's own type is the one to use.
                Some(t) if keys::fits(self.via, &t, wire, any_hash) => {
                    return Ok(if self.via == Via::Bridge { wire.clone() } else { t })
                }
                Some(t) => other = Some(t),
                None => {}
            }
        }
    }

    /// Waits until a server of `action` (named `name`) is in the graph, until `deadline`, and tells which
    /// CancelGoal type to call it with.
    pub async fn wait_for_action(
        &self,
        name: &str,
        action: &ActionType,
        deadline: Instant,
    ) -> Result<ServiceType, String> {
        let part = |s: &str| format!("{}/_action/{s}", name.trim_end_matches('/'));
        let mut cancel = action.cancel_goal.clone();
        match self.via {
            Via::RmwZenoh => {
                self.wait_for(Kind::Service, &part("send_goal"), &action.send_goal.wire, false, deadline).await?;
                // CancelGoal is action_msgs' own, the same for every action, yet implementations hash it
                // differently (hiroz 0.2.1 leaves `goals_canceling` out): cancel on the key the server announces.
                cancel.wire = self.wait_for(Kind::Service, &part("cancel_goal"), &cancel.wire, true, deadline).await?;
            }
            Via::Bridge => {
                let wire = WireType { dds_name: keys::dds_type(&action.name), hash: String::new() };
                self.wait_for(Kind::ActionServer, name, &wire, false, deadline).await?;
            }
        }
        Ok(cancel)
    }

    /// Announces an action client as a bridge does, as a whole (rmw_zenoh announces its parts instead).
    pub async fn announce_action_client(
        &self,
        name: &str,
        action: &ActionType,
    ) -> Result<Option<LivelinessToken>, String> {
        if self.via != Via::Bridge {
            return Ok(None);
        }
        let key = keys::bridge_token(&self.id.zid, Kind::ActionClient, name, &action.name);
        Ok(Some(announce(&self.session, key, &format!("the ROS 2 action client for {name}")).await?))
    }

    /// Subscribes to `topic` as rmw_zenoh does: the data key of its type, and the subscription's token.
    pub async fn subscription(&self, topic: &str, wire: &WireType) -> Result<(Endpoint, Subscription), String> {
        let endpoint = self.endpoint(Kind::Subscription, topic, wire, keys::TOPIC_QOS).await?;
        let subscriber =
            baton_host::traffic::subscriber(&self.session, keys::data(self.via, self.id.domain, topic, wire))
                .await
                .map_err(|e| format!("cannot subscribe to {topic}: {e}"))?;
        Ok((endpoint, subscriber))
    }

    /// A publication on `topic`, announced in the graph; its messages carry rmw_zenoh's attachment.
    pub async fn publisher(&self, topic: &str, ty: &TopicType) -> Result<TopicPublisher, String> {
        let endpoint = self.endpoint(Kind::Publisher, topic, &ty.wire, keys::TOPIC_QOS).await?;
        let publisher =
            baton_host::traffic::publisher(&self.session, keys::data(self.via, self.id.domain, topic, &ty.wire))
                .congestion_control(CongestionControl::Block)
                .await
                .map_err(|e| format!("cannot publish on {topic}: {e}"))?;
        Ok(TopicPublisher { endpoint, publisher, sequence: 0 })
    }

    /// Calls a service: the request's CDR bytes in, the response's out. `timeout` bounds the wait for the answer.
    /// A query that no server took (it ends at once, without a reply: a server whose liveliness token reached us
    /// before its queryable reached the router, as zenoh-ros2-sdk declares them) reached no server, so it is
    /// sent again, for up to `UNMATCHED_RETRY`; a server that took it and never answered is waited for until
    /// the timeout.
    pub async fn call(
        &self,
        name: &str,
        service: &ServiceType,
        client: &Endpoint,
        request: Vec<u8>,
        timeout: Option<Duration>,
    ) -> Result<Vec<u8>, String> {
        let key = keys::data(self.via, self.id.domain, name, &service.wire);
        let limit = timeout.unwrap_or(CALL_TIMEOUT_MAX).min(CALL_TIMEOUT_MAX);
        let started = Instant::now();
        let mut pause = FIRST_PAUSE;
        let answer = loop {
            let sequence = self.next_sequence.fetch_add(1, Ordering::Relaxed);
            let sent = Instant::now();
            let left = limit.saturating_sub(sent - started);
            let replies = baton_host::traffic::get(&self.session, key.clone())
                .payload(request.clone())
                .attachment(keys::attachment(sequence, now_ns(), &client.gid))
                .target(match self.via {
                    Via::RmwZenoh => QueryTarget::AllComplete,
                    // The bridge's queryables do not say they are complete.
                    Via::Bridge => QueryTarget::BestMatching,
                })
                .consolidation(ConsolidationMode::None)
                .timeout(left)
                .await
                .map_err(|e| format!("cannot call {name}: {e}"))?;
            let answer = replies.recv_async().await;
            let unmatched = answer.is_err() && sent.elapsed() < left / 2;
            if !unmatched || started.elapsed() + pause >= UNMATCHED_RETRY.min(limit) {
                break answer;
            }
            if pause == FIRST_PAUSE {
                // The agent's log (stderr), as the host writes it, and its trace: a server seen in the graph that
                // takes no call.
                let said = "no server took the call yet, though one is in the graph: sending it again";
                eprintln!("warning: {said} ({name})");
                crate::trace::event(&self.agent, TraceEvent::SkillWait, name, Some(said.to_string()));
            }
            tokio::time::sleep(pause).await;
            pause = (pause * 2).min(Duration::from_millis(200));
        };
        match answer {
            Ok(reply) => match reply.result() {
                Ok(sample) => Ok(sample.payload().to_bytes().into_owned()),
                Err(e) => {
                    Err(format!("{name} answered with an error: {}", String::from_utf8_lossy(&e.payload().to_bytes())))
                }
            },
            Err(_) => Err(match timeout {
                Some(t) => format!("{name} did not answer within {} ms (or its server went away)", t.as_millis()),
                None => format!("the server of {name} went away before it answered"),
            }),
        }
    }
}
