//! `opcua_method`: calls a method of a machine's OPC UA server and, for a long job, follows it on the server's
//! nodes. The mapping to IEC semantics:
//! - the action's Q rises: the agent opens a session, reads the method's InputArguments, converts `args` to the
//!   declared types and calls the method;
//! - done: the call answered Good — or, with `done_node`, once that node reads TRUE after the call;
//! - fault: a Bad (or Uncertain) answer, an argument that does not fit its type, `fault_node` TRUE, the
//!   connection lost, or no end within `timeout_ms` (connecting, calling and the job together);
//! - Q falls first: before the method was called, nothing is called; after, the method named by `cancel_method`
//!   (on the same object, no arguments) is called if given, and the skill ends once it answered
//!   (`Skill::stops_itself`). The agent starts the action's next job only once that answer came, so a cancel
//!   never reaches the job of a step entered again.
//!
//! `outputs := '[0] => count'` writes the method's output arguments to chart variables; `result_nodes := 'ns=2;
//! s=Cell.Count, …'` are read when the job is done, and `result := '[0] => count'` writes them.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use baton_proto::front::literal::{self, Literal};
use baton_proto::front::pragma::Param;
use opcua::client::{DataChangeCallback, MonitoredItem, Session};
use opcua::types::{
    BrowseDescription, BrowseDirection, BrowseResultMask, CallMethodRequest, DataValue, NodeClassMask, NodeId,
    ReadValueId, ReferenceTypeId, TimestampsToReturn, Variant,
};
use tokio::sync::mpsc;

use super::convert::{self, DataType};
use super::{node_id, parse_node, status, Endpoint, OpcUa};
use crate::skill::{outputs_of, Skill, SkillCall, SkillFuture};

const TIMEOUT_MS_DEFAULT: f64 = 10_000.0;
/// How long a cancel method may take: the chart has moved on, so the agent does not wait longer.
const CANCEL_WAIT: Duration = Duration::from_secs(5);
/// The publishing interval asked of the server while waiting for `done_node`.
const WATCH_INTERVAL: Duration = Duration::from_millis(20);

/// A call's parameters, read: where checking and starting both begin.
struct Method {
    endpoint: Endpoint,
    object: NodeId,
    method: NodeId,
    args: Vec<Literal>,
    done: Option<NodeId>,
    fault: Option<NodeId>,
    cancel: Option<NodeId>,
    result_nodes: Vec<NodeId>,
    timeout: Duration,
}

fn method(params: &BTreeMap<String, Param>) -> Result<Method, String> {
    let endpoint = Endpoint::from_params(params, "opcua_method")?;
    let needs = |key: &str, example: &str| format!("the opcua_method skill needs `{key} := '{example}'`");
    let object = node_id(params, "object")?.ok_or_else(|| needs("object", "ns=2;s=Cell"))?;
    let method = node_id(params, "method")?.ok_or_else(|| needs("method", "ns=2;s=Cell.Pick"))?;
    let args = match params.get("args") {
        None => Vec::new(),
        Some(Param::Str(text)) => match literal::parse(text).map_err(|e| format!("`args` cannot be read: {e}"))? {
            Literal::Array(items) => items,
            _ => return Err(format!("`args` must be an array literal such as '[3, 2.5]', not `{text}`")),
        },
        Some(Param::Value(v)) => return Err(format!("`args` must be an array literal such as '[3, 2.5]', not {v}")),
    };
    let timeout_ms = params.get("timeout_ms").and_then(Param::as_f64).unwrap_or(TIMEOUT_MS_DEFAULT);
    if !(1.0..=86_400_000.0).contains(&timeout_ms) {
        return Err(format!("`timeout_ms` must be between 1 and 86400000, not {timeout_ms}"));
    }
    let result_nodes = match params.get("result_nodes") {
        None => Vec::new(),
        Some(Param::Str(text)) => text
            .split(',')
            .map(|n| parse_node(n).map_err(|e| format!("`result_nodes`: {e}")))
            .collect::<Result<_, _>>()?,
        Some(Param::Value(v)) => return Err(format!("`result_nodes` must list node ids, not {v}")),
    };
    Ok(Method {
        endpoint,
        object,
        method,
        args,
        done: node_id(params, "done_node")?,
        fault: node_id(params, "fault_node")?,
        cancel: node_id(params, "cancel_method")?,
        result_nodes,
        timeout: Duration::from_millis(timeout_ms as u64),
    })
}

/// `{skill := 'opcua_method', endpoint := 'opc.tcp://127.0.0.1:4840', object := 'ns=2;s=Cell', method :=
/// 'ns=2;s=Cell.Pick', args := '[3]', done_node := 'ns=2;s=Cell.Done', cancel_method := 'ns=2;s=Cell.Stop'}`.
pub struct OpcuaMethod {
    pub opcua: Arc<OpcUa>,
}

impl Skill for OpcuaMethod {
    fn check(&self, params: &BTreeMap<String, Param>) -> Result<(), String> {
        method(params).map(|_| ())
    }

    fn start(&self, call: SkillCall) -> SkillFuture {
        let opcua = Arc::clone(&self.opcua);
        Box::pin(async move {
            let m = method(&call.params)?;
            let deadline = Instant::now() + m.timeout;
            let mut link = tokio::select! {
                link = opcua.connect(&m.endpoint, deadline) => link?,
                // Nothing was asked of the machine yet: there is nothing to cancel.
                () = call.ctx.stopped() => return Ok(()),
            };
            let session = Arc::clone(&link.session);
            // Whether the method was called: a stop before that has nothing to cancel.
            let called = std::sync::atomic::AtomicBool::new(false);
            let outcome = tokio::select! {
                r = job(&session, &m, &call, &called) => Outcome::Ended(r),
                why = link.lost() => Outcome::Ended(Err(why)),
                () = tokio::time::sleep_until(deadline.into()) => Outcome::Ended(Err(format!(
                    "{} did not end within timeout_ms = {} ms", show(&m.method), m.timeout.as_millis()
                ))),
                () = call.ctx.stopped() => Outcome::Stopped,
            };
            let result = match outcome {
                Outcome::Ended(r) => r,
                Outcome::Stopped if called.load(std::sync::atomic::Ordering::SeqCst) => cancel(&session, &m).await,
                Outcome::Stopped => Ok(()),
            };
            link.close().await;
            result
        })
    }

    fn stops_itself(&self) -> bool {
        true
    }
}

enum Outcome {
    Ended(Result<(), String>),
    Stopped,
}

fn show(node: &NodeId) -> String {
    node.to_string()
}

/// The call and, with `done_node`, the job it starts.
async fn job(
    session: &Session,
    m: &Method,
    call: &SkillCall,
    called: &std::sync::atomic::AtomicBool,
) -> Result<(), String> {
    let declared = input_arguments(session, &m.method).await?;
    if declared.len() != m.args.len() {
        return Err(format!(
            "{} takes {} argument(s) ({}), and `args` gives {}",
            show(&m.method),
            declared.len(),
            declared.iter().map(|a| a.0.as_str()).collect::<Vec<_>>().join(", "),
            m.args.len()
        ));
    }
    let mut args = Vec::with_capacity(m.args.len());
    for (i, (lit, (name, ty, array))) in m.args.iter().zip(&declared).enumerate() {
        let which = if name.is_empty() { format!("argument {}", i + 1) } else { format!("argument `{name}`") };
        args.push(convert::to_variant(lit, *ty, *array).map_err(|e| format!("{which} of {}: {e}", show(&m.method)))?);
    }
    let request =
        CallMethodRequest { object_id: m.object.clone(), method_id: m.method.clone(), input_arguments: Some(args) };
    // The action may have ended while the arguments were read: then nothing is started.
    if call.ctx.is_stopped() {
        return Ok(());
    }
    called.store(true, std::sync::atomic::Ordering::SeqCst);
    let answer = session
        .call(vec![request])
        .await
        .map_err(|e| format!("calling {}: {}", show(&m.method), status(e.status())))?
        .into_iter()
        .next()
        .ok_or_else(|| format!("{} gave no result for the call", m.endpoint.url))?;
    if !answer.status_code.is_good() {
        let bad_args: Vec<String> = answer
            .input_argument_results
            .unwrap_or_default()
            .iter()
            .enumerate()
            .filter(|(_, s)| !s.is_good())
            .map(|(i, s)| format!("argument {} {}", i + 1, status(*s)))
            .collect();
        let detail = if bad_args.is_empty() { String::new() } else { format!(" ({})", bad_args.join(", ")) };
        return Err(format!("{} answered {}{detail}", show(&m.method), status(answer.status_code)));
    }
    let outputs = answer.output_arguments.unwrap_or_default();
    write(call, "outputs", &outputs)?;
    if let Some(done) = &m.done {
        wait_for_job(session, done, m.fault.as_ref()).await?;
    }
    if !m.result_nodes.is_empty() {
        let values = read_values(session, &m.result_nodes).await?;
        write(call, "result", &values)?;
    }
    Ok(())
}

fn write(call: &SkillCall, key: &str, values: &[Variant]) -> Result<(), String> {
    for (i, path) in outputs_of(&call.outputs, key) {
        let v = convert::value_at(values, path).map_err(|e| format!("`{key}`: {e}"))?;
        call.ctx.write(i, v);
    }
    Ok(())
}

/// The method's declared arguments: name, data type, whether an array. A method with no InputArguments
/// property takes none.
async fn input_arguments(session: &Session, method: &NodeId) -> Result<Vec<(String, DataType, bool)>, String> {
    let browse = BrowseDescription {
        node_id: method.clone(),
        browse_direction: BrowseDirection::Forward,
        reference_type_id: ReferenceTypeId::HasProperty.into(),
        include_subtypes: true,
        node_class_mask: NodeClassMask::VARIABLE.bits(),
        result_mask: BrowseResultMask::All as u32,
    };
    let results = session
        .browse(&[browse], 100, None)
        .await
        .map_err(|e| format!("browsing {}: {}", show(method), status(e.status())))?;
    let result = results.into_iter().next().ok_or_else(|| format!("no browse result for {}", show(method)))?;
    if !result.status_code.is_good() {
        return Err(format!("{}: {}", show(method), status(result.status_code)));
    }
    let property = result
        .references
        .unwrap_or_default()
        .into_iter()
        .find(|r| r.browse_name.name.as_ref() == "InputArguments")
        .map(|r| r.node_id.node_id);
    let Some(property) = property else { return Ok(Vec::new()) };
    let values = read_values(session, &[property]).await?;
    let list = match values.into_iter().next() {
        Some(Variant::Array(a)) => a.values,
        Some(Variant::Empty) | None => Vec::new(),
        Some(one) => vec![one],
    };
    list.iter()
        .enumerate()
        .map(|(i, v)| {
            let Variant::ExtensionObject(obj) = v else {
                return Err(format!("{}: InputArguments[{i}] is not an Argument", show(method)));
            };
            let arg = obj
                .inner_as::<opcua::types::Argument>()
                .ok_or_else(|| format!("{}: InputArguments[{i}] is not an Argument", show(method)))?;
            let name = arg.name.as_ref().to_string();
            let ty = DataType::of(&arg.data_type).ok_or_else(|| {
                format!(
                    "{}: argument `{name}` is of data type {}, which a chart cannot give",
                    show(method),
                    arg.data_type
                )
            })?;
            Ok((name, ty, arg.value_rank >= 1))
        })
        .collect()
}

async fn read_values(session: &Session, nodes: &[NodeId]) -> Result<Vec<Variant>, String> {
    let ids: Vec<ReadValueId> = nodes.iter().map(|n| ReadValueId::from(n.clone())).collect();
    let values = session.read(&ids, TimestampsToReturn::Neither, 0.0).await.map_err(|e| {
        format!("reading {}: {}", nodes.iter().map(show).collect::<Vec<_>>().join(", "), status(e.status()))
    })?;
    if values.len() != nodes.len() {
        return Err(format!("asked for {} values, the server gave {}", nodes.len(), values.len()));
    }
    nodes.iter().zip(values).map(|(node, dv)| value_of(node, dv)).collect()
}

fn value_of(node: &NodeId, dv: DataValue) -> Result<Variant, String> {
    match dv.status {
        Some(s) if !s.is_good() => Err(format!("{}: {}", show(node), status(s))),
        _ => Ok(dv.value.unwrap_or_default()),
    }
}

/// Waits until `done` reads TRUE (Ok) or `fault` does (Err), watching both through a subscription.
async fn wait_for_job(session: &Session, done: &NodeId, fault: Option<&NodeId>) -> Result<(), String> {
    let (tx, mut rx) = mpsc::unbounded_channel::<(NodeId, DataValue)>();
    let callback = DataChangeCallback::new(move |dv: DataValue, item: &MonitoredItem| {
        let _ = tx.send((item.item_to_monitor().node_id.clone(), dv));
    });
    let subscription = session
        .create_subscription(WATCH_INTERVAL, 100, 10, 0, 0, true, callback)
        .await
        .map_err(|e| format!("cannot watch {}: {}", show(done), status(e.status())))?;
    let watched: Vec<NodeId> = std::iter::once(done.clone()).chain(fault.cloned()).collect();
    let created = session
        .create_monitored_items(
            subscription,
            TimestampsToReturn::Neither,
            watched.iter().cloned().map(Into::into).collect(),
        )
        .await
        .map_err(|e| format!("cannot watch {}: {}", show(done), status(e.status())))?;
    for (node, item) in watched.iter().zip(&created) {
        if !item.result.status_code.is_good() {
            return Err(format!("cannot watch {}: {}", show(node), status(item.result.status_code)));
        }
    }
    let outcome = loop {
        let Some((node, dv)) = rx.recv().await else {
            break Err(format!("the watch on {} ended", show(done)));
        };
        let value = value_of(&node, dv)?;
        let set = matches!(value, Variant::Boolean(true));
        if !set && !matches!(value, Variant::Boolean(false)) {
            break Err(format!("{} holds {value:?}, not a BOOL", show(&node)));
        }
        if set && fault == Some(&node) {
            break Err(format!("{} became TRUE", show(&node)));
        }
        if set && &node == done {
            break Ok(());
        }
    };
    let _ = session.delete_subscription(subscription).await;
    outcome
}

/// The step was left: calls `cancel_method`, if any, and says how that went.
async fn cancel(session: &Session, m: &Method) -> Result<(), String> {
    let Some(cancel) = &m.cancel else { return Ok(()) };
    let request = CallMethodRequest { object_id: m.object.clone(), method_id: cancel.clone(), input_arguments: None };
    match tokio::time::timeout(CANCEL_WAIT, session.call(vec![request])).await {
        Err(_) => Err(format!("{} did not answer within {} s", show(cancel), CANCEL_WAIT.as_secs())),
        Ok(Err(e)) => Err(format!("calling {}: {}", show(cancel), status(e.status()))),
        Ok(Ok(results)) => match results.first() {
            Some(r) if r.status_code.is_good() => Ok(()),
            Some(r) => Err(format!("{} answered {}", show(cancel), status(r.status_code))),
            None => Err(format!("{} gave no result", show(cancel))),
        },
    }
}
