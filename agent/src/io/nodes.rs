//! Variables bound to OPC UA nodes, with async-opcua's client (`crate::opcua`): one session per server (its
//! endpoint, security and user) for every node of a run bound on it.
//! - an input is a monitored item of one subscription, sampled every `interval_ms` (default 100 ms); each
//!   change of the node's value becomes the variable's;
//! - an output is written on every change of the variable, converted to the node's DataType (a DINT of the
//!   chart written to an Int16 node that cannot hold it is an error, not a wrapped value).
//!
//! A server that cannot be reached, or goes away, is reported for each of its bindings, the variables keep
//! their values, and the agent tries again (from 0.5 s, doubling, up to every 5 s). When the session is back,
//! the outputs' latest values are written again: a machine that restarted gets the chart's outputs back, as a
//! PLC's output image is written every scan.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use baton_proto::cluster::bindings::{IoBinding, IoDir};
use baton_proto::front::literal::Literal;
use baton_proto::front::pragma::Param;
use baton_proto::types::Value;
use opcua::client::{DataChangeCallback, MonitoredItem, Session};
use opcua::types::{
    AttributeId, DataValue, MonitoredItemCreateRequest, MonitoringMode, MonitoringParameters, NodeId, NumericRange,
    QualifiedName, ReadValueId, TimestampsToReturn, Variant, WriteValue,
};
use tokio::sync::mpsc;

use crate::opcua::convert::{self, DataType};
use crate::opcua::{parse_node, status, Endpoint, Link, OpcUa};

use super::shared::{Latest, Sink, RETRY_FIRST, RETRY_MAX};

/// How long one attempt to open a session may take.
const CONNECT_ATTEMPT: Duration = Duration::from_secs(3);
const INTERVAL_MS_DEFAULT: f64 = 100.0;

/// The bindings that share a session: the same endpoint, security and identity.
pub fn server_key(b: &IoBinding) -> String {
    let text = |k: &str| b.params.get(k).and_then(Param::as_str).unwrap_or("").to_string();
    ["endpoint", "security", "policy", "user", "password"].map(text).join("\u{1f}")
}

struct Bound {
    binding: usize,
    dir: IoDir,
    node: NodeId,
    interval_ms: f64,
}

/// Serves the bindings of one server for as long as the run lasts.
pub async fn server(opcua: Arc<OpcUa>, bindings: Vec<(usize, IoBinding)>, latest: Arc<Latest>, sink: Sink) {
    let Some((_, first)) = bindings.first() else { return };
    let endpoint = match Endpoint::from_params(&first.params, "OPC UA binding") {
        Ok(e) => e,
        Err(why) => {
            for (i, _) in &bindings {
                sink.state(*i, Err(why.clone()));
            }
            return;
        }
    };
    let mut bound = Vec::new();
    for (i, b) in &bindings {
        let node = b.node().map_or(Err("the binding names no node".to_string()), |(_, n)| parse_node(n));
        match node {
            Ok(node) => bound.push(Bound {
                binding: *i,
                dir: b.dir,
                node,
                interval_ms: b.params.get("interval_ms").and_then(Param::as_f64).unwrap_or(INTERVAL_MS_DEFAULT),
            }),
            Err(why) => sink.state(*i, Err(why)),
        }
    }
    // The outputs' latest values: written when they change, and again on every new session.
    let mut outputs: BTreeMap<usize, Value> = BTreeMap::new();
    let mut wait = RETRY_FIRST;
    loop {
        let why = match opcua.connect(&endpoint, Instant::now() + CONNECT_ATTEMPT).await {
            Ok(mut link) => {
                wait = RETRY_FIRST;
                let why = serve(&mut link, &bound, &latest, &mut outputs, &sink).await;
                link.close().await;
                why
            }
            Err(why) => why,
        };
        for b in &bound {
            sink.state(b.binding, Err(why.clone()));
        }
        // Meanwhile the outputs' newest values are kept for the next session.
        let pause = tokio::time::sleep(wait);
        tokio::pin!(pause);
        loop {
            tokio::select! {
                () = &mut pause => break,
                values = latest.next() => outputs.extend(values),
            }
        }
        wait = (wait * 2).min(RETRY_MAX);
    }
}

/// Serves the bindings over one session until it is lost; says why it was.
async fn serve(
    link: &mut Link,
    bound: &[Bound],
    latest: &Latest,
    outputs: &mut BTreeMap<usize, Value>,
    sink: &Sink,
) -> String {
    let session = Arc::clone(&link.session);
    // What each output node holds: its data type, read once per session.
    let mut types: BTreeMap<usize, DataType> = BTreeMap::new();
    for b in bound.iter().filter(|b| b.dir == IoDir::Output) {
        match data_type(&session, &b.node).await {
            Ok(ty) => {
                types.insert(b.binding, ty);
            }
            Err(why) => sink.state(b.binding, Err(why)),
        }
    }
    let (tx, mut changes) = mpsc::unbounded_channel::<(NodeId, DataValue)>();
    let inputs: Vec<&Bound> = bound.iter().filter(|b| b.dir == IoDir::Input).collect();
    if !inputs.is_empty() {
        if let Err(why) = watch(&session, &inputs, tx, sink).await {
            return why;
        }
    }
    for b in bound.iter().filter(|b| types.contains_key(&b.binding)) {
        sink.state(b.binding, Ok(()));
    }
    let mut written_bad: BTreeMap<usize, bool> = BTreeMap::new();
    let again: Vec<(usize, Value)> = outputs.iter().map(|(b, v)| (*b, v.clone())).collect();
    for (binding, value) in again {
        write(&session, bound, &types, binding, &value, sink, &mut written_bad).await;
    }
    let mut input_bad: BTreeMap<usize, bool> = BTreeMap::new();
    loop {
        tokio::select! {
            why = link.lost() => return why,
            values = latest.next() => {
                for (binding, value) in values {
                    outputs.insert(binding, value.clone());
                    write(&session, bound, &types, binding, &value, sink, &mut written_bad).await;
                }
            }
            Some((node, dv)) = changes.recv() => {
                for b in inputs.iter().filter(|b| b.node == node) {
                    let value = match dv.status {
                        Some(s) if !s.is_good() => Err(format!("{node}: {}", status(s))),
                        _ => convert::from_variant(dv.value.as_ref().unwrap_or(&Variant::Empty))
                            .map_err(|e| format!("{node}: {e}")),
                    };
                    let was_bad = input_bad.insert(b.binding, value.is_err()).unwrap_or(false);
                    match value {
                        Ok(v) => {
                            if was_bad {
                                sink.state(b.binding, Ok(()));
                            }
                            sink.value(b.binding, v);
                        }
                        Err(why) => sink.state(b.binding, Err(why)),
                    }
                }
            }
        }
    }
}

/// Monitors the input nodes in one subscription; each one the server refuses is reported by itself.
async fn watch(
    session: &Session,
    inputs: &[&Bound],
    tx: mpsc::UnboundedSender<(NodeId, DataValue)>,
    sink: &Sink,
) -> Result<(), String> {
    let fastest = inputs.iter().map(|b| b.interval_ms).fold(f64::INFINITY, f64::min);
    let callback = DataChangeCallback::new(move |dv: DataValue, item: &MonitoredItem| {
        let _ = tx.send((item.item_to_monitor().node_id.clone(), dv));
    });
    let subscription = session
        .create_subscription(Duration::from_millis(fastest as u64), 100, 10, 0, 0, true, callback)
        .await
        .map_err(|e| format!("cannot subscribe: {}", status(e.status())))?;
    let requests = inputs
        .iter()
        .map(|b| {
            let parameters = MonitoringParameters {
                sampling_interval: b.interval_ms,
                queue_size: 1,
                discard_oldest: true,
                ..Default::default()
            };
            MonitoredItemCreateRequest::new(b.node.clone().into(), MonitoringMode::Reporting, parameters)
        })
        .collect();
    let created = session
        .create_monitored_items(subscription, TimestampsToReturn::Neither, requests)
        .await
        .map_err(|e| format!("cannot monitor the nodes: {}", status(e.status())))?;
    for (b, item) in inputs.iter().zip(&created) {
        let code = item.result.status_code;
        sink.state(b.binding, if code.is_good() { Ok(()) } else { Err(format!("{}: {}", b.node, status(code))) });
    }
    Ok(())
}

/// The data type of a variable node, as one a chart can write.
async fn data_type(session: &Session, node: &NodeId) -> Result<DataType, String> {
    let read = |attribute: AttributeId| ReadValueId {
        node_id: node.clone(),
        attribute_id: attribute as u32,
        index_range: NumericRange::None,
        data_encoding: QualifiedName::null(),
    };
    let values = session
        .read(&[read(AttributeId::DataType), read(AttributeId::ValueRank)], TimestampsToReturn::Neither, 0.0)
        .await
        .map_err(|e| format!("reading {node}: {}", status(e.status())))?;
    let [ty, rank] = values.as_slice() else {
        return Err(format!("reading {node}: the server gave {} values for 2", values.len()));
    };
    for dv in [ty, rank] {
        if let Some(s) = dv.status.filter(|s| !s.is_good()) {
            return Err(format!("{node}: {}", status(s)));
        }
    }
    let Some(Variant::NodeId(id)) = &ty.value else {
        return Err(format!("{node} is not a variable (it has no data type)"));
    };
    if matches!(rank.value, Some(Variant::Int32(r)) if r >= 1) {
        return Err(format!("{node} holds an array: bind a variable to a node that holds one value"));
    }
    DataType::of(id).ok_or_else(|| format!("{node} is of data type {id}, which a chart variable cannot be written to"))
}

/// Writes an output's value to its node, and says when that failed (or works again).
async fn write(
    session: &Session,
    bound: &[Bound],
    types: &BTreeMap<usize, DataType>,
    binding: usize,
    value: &Value,
    sink: &Sink,
    bad: &mut BTreeMap<usize, bool>,
) {
    let (Some(b), Some(ty)) = (bound.iter().find(|b| b.binding == binding), types.get(&binding)) else { return };
    let lit = match value {
        Value::Str(s) => Literal::Text(s.to_string()),
        other => Literal::Scalar(other.clone()),
    };
    let outcome = match convert::to_variant(&lit, *ty, false) {
        Err(e) => Err(format!("{value} cannot be written to {}: {e}", b.node)),
        Ok(variant) => {
            let request =
                WriteValue::new(b.node.clone(), AttributeId::Value, NumericRange::None, DataValue::value_only(variant));
            match session.write(&[request]).await {
                Err(e) => Err(format!("writing {}: {}", b.node, status(e.status()))),
                Ok(codes) => match codes.first() {
                    Some(c) if c.is_good() => Ok(()),
                    Some(c) => Err(format!("writing {value} to {}: {}", b.node, status(*c))),
                    None => Err(format!("writing {}: no answer", b.node)),
                },
            }
        }
    };
    let was_bad = bad.insert(binding, outcome.is_err()).unwrap_or(false);
    match outcome {
        Err(why) => sink.state(binding, Err(why)),
        Ok(()) if was_bad => sink.state(binding, Ok(())),
        Ok(()) => {}
    }
}
