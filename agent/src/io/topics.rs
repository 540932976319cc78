//! Variables bound to a field of a ROS 2 topic's messages, over rmw_zenoh (`crate::ros2`):
//! - an input subscribes to the topic and takes the field of every message. It is reachable while a publisher
//!   of the topic's type is in the ROS graph (or messages come); none, or only publishers of another type, and
//!   it is reported unreachable — a sensor whose driver died is a device down, not a silent FALSE;
//! - an output publishes a message whenever the variable changes: the field set, every other field at its
//!   default (a `geometry_msgs/msg/Twist` with only `linear.x`). With `period_ms`, it also publishes the value
//!   again at that period: drivers that stop a robot when its commands stop coming get them, and a subscriber
//!   that joins late hears the value (topics are volatile: a change published before it joined is gone).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Duration;

use baton_proto::cluster::bindings::IoBinding;
use baton_proto::front::literal::{Literal, PathPart};
use baton_proto::types::Value;
use zenoh::sample::SampleKind;
use zenoh::Session;

use crate::ros2::interfaces::{TopicType, WireType};
use crate::ros2::rmw_keys::{self as keys, Kind};
use crate::ros2::{cdr, Ros2};

use super::shared::{Latest, Resend, Sink};

/// How long an input waits for the ROS graph to show a publisher before it says there is none: the graph's
/// tokens arrive within milliseconds of the subscription on a live router.
const PUBLISHER_GRACE: Duration = Duration::from_secs(1);

/// The topic, its type and the resolved field of a binding, checked against the type's definition.
fn resolve(ros2: &Ros2, b: &IoBinding, settable: bool) -> Result<(String, TopicType, Vec<PathPart>), String> {
    let (topic, ty) = b.topic().ok_or("the binding names no topic")?;
    let found = ros2.lib.topic(ty)?;
    let path = cdr::resolve_path(&ros2.lib, &found.msg, &b.field(), settable).map_err(|e| format!("{topic}: {e}"))?;
    Ok((topic.to_string(), found, path))
}

pub async fn input(ros2: Arc<Ros2>, session: Session, binding: usize, b: IoBinding, sink: Sink) {
    if let Err(why) = follow(&ros2, &session, binding, &b, &sink).await {
        sink.state(binding, Err(why));
    }
}

async fn follow(ros2: &Ros2, session: &Session, binding: usize, b: &IoBinding, sink: &Sink) -> Result<(), String> {
    let (topic, ty, path) = resolve(ros2, b, false)?;
    let node = ros2.node(session).await?;
    let (_endpoint, subscriber) = node.subscription(&topic, &ty.wire).await?;
    let graph = baton_host::traffic::liveliness_subscriber(
        session,
        keys::servers(node.via(), node.domain(), Kind::Publisher, &topic),
    )
    .history(true)
    .await
    .map_err(|e| format!("cannot watch the ROS graph: {e}"))?;
    // Publishers in the graph by token: those of our type, and those of another (which never reach us).
    let mut ours: BTreeSet<String> = BTreeSet::new();
    let mut others: BTreeMap<String, WireType> = BTreeMap::new();
    let mut heard = false;
    let mut unreadable: Option<String> = None;
    let mut graced = false;
    let grace = tokio::time::sleep(PUBLISHER_GRACE);
    tokio::pin!(grace);
    let mut said: Option<Result<(), String>> = None;
    loop {
        tokio::select! {
            sample = subscriber.recv_async() => {
                let Ok(sample) = sample else { return Err("the Zenoh session closed".into()) };
                heard = true;
                let bytes = sample.payload().to_bytes();
                match cdr::decode(&ros2.lib, &ty.msg, &bytes).and_then(|m| m.value_at(&path)) {
                    Ok(value) => {
                        unreadable = None;
                        sink.value(binding, value);
                    }
                    Err(e) => unreadable = Some(format!("a message on {topic} cannot be read as a {}: {e}", ty.msg.name)),
                }
            }
            token = graph.recv_async() => {
                let Ok(token) = token else { return Err("the Zenoh session closed".into()) };
                let key = token.key_expr().as_str().to_string();
                match token.kind() {
                    SampleKind::Put => match keys::announced_type(node.via(), &key) {
                        Some(t) if keys::fits(node.via(), &t, &ty.wire, false) => {
                            ours.insert(key);
                        }
                        Some(t) => {
                            others.insert(key, t);
                        }
                        None => {}
                    },
                    SampleKind::Delete => {
                        ours.remove(&key);
                        others.remove(&key);
                        if ours.is_empty() {
                            heard = false;
                        }
                    }
                }
            }
            () = &mut grace, if !graced => graced = true,
        }
        if !graced && ours.is_empty() && !heard {
            continue;
        }
        let state = match (&unreadable, ours.is_empty() && !heard, others.values().next()) {
            (Some(why), _, _) => Err(why.clone()),
            (None, false, _) => Ok(()),
            (None, true, Some(t)) => Err(format!(
                "the publisher of {topic} on {} has type {}, not {}: the two sides were built from different definitions or ROS 2 distributions",
                node.graph(), keys::describe(node.via(), t), keys::describe(node.via(), &ty.wire)
            )),
            (None, true, None) => Err(format!("no publisher of {topic} ({}) on {}", ty.msg.name, node.graph())),
        };
        if said.as_ref() != Some(&state) {
            sink.state(binding, state.clone());
            said = Some(state);
        }
    }
}

pub async fn output(ros2: Arc<Ros2>, session: Session, binding: usize, b: IoBinding, latest: Arc<Latest>, sink: Sink) {
    let setup = async {
        let (topic, ty, path) = resolve(&ros2, &b, true)?;
        let node = ros2.node(&session).await?;
        let publisher = node.publisher(&topic, &ty).await?;
        Ok::<_, String>((topic, ty, path, publisher, node))
    };
    let (topic, ty, path, mut publisher, _node) = match setup.await {
        Ok(s) => s,
        Err(why) => return sink.state(binding, Err(why)),
    };
    let mut down = false;
    let mut resend = Resend::new(binding, b.period_ms());
    loop {
        let value = resend.next(&latest).await;
        let lit = match value {
            Value::Str(s) => Literal::Text(s.to_string()),
            other => Literal::Scalar(other),
        };
        let sent = cdr::encode(&ros2.lib, &ty.msg, Some(&cdr::literal_at(&path, lit)))
            .map_err(|e| format!("{topic}: {e}"))
            .map(|bytes| publisher.put(bytes));
        let sent = match sent {
            Ok(put) => put.await.map_err(|e| format!("{topic}: {e}")),
            Err(e) => Err(e),
        };
        match sent {
            Ok(()) if std::mem::take(&mut down) => sink.state(binding, Ok(())),
            Ok(()) => {}
            Err(why) => {
                down = true;
                sink.state(binding, Err(why));
            }
        }
    }
}
