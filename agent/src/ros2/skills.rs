//! The ROS 2 skills: `ros2_service` calls a service, `ros2_action` sends a goal to an action server and follows
//! it to its result, both over rmw_zenoh with no ROS installation. The mapping to IEC semantics:
//! - the action's Q rises: the request or goal is sent (once the server is in the ROS graph, within
//!   `timeout_ms`);
//! - done: the response came (and its `fault_if_false` field is TRUE); the goal's result came back SUCCEEDED;
//! - fault: no server within `timeout_ms`, the goal rejected, aborted or cancelled by the server, a response
//!   that says FALSE, an answer that does not fit its type;
//! - Q falls first: a service call is abandoned (a service cannot be cancelled); a goal is cancelled on the
//!   server, and the skill ends once the server answered (`Skill::stops_itself`).
//!
//! Mappings write parts of the answer to chart variables the agent owns: `response := 'message => text'`,
//! `result := 'sequence[4] => last'`, `feedback := 'sequence[1] => partial'` (the latest feedback).

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use baton_proto::front::literal::{self, Literal};
use baton_proto::front::pragma::Param;
use baton_proto::types::Value;
use baton_ros2::cdr::{self, RosValue};
use baton_ros2::interfaces::{ActionType, Interfaces, ServiceType};

use crate::skill::{outputs_of, Skill, SkillCall, SkillFuture};

use super::client::{Node, Ros2};
use super::rmw_keys::{self as keys, Kind};

const TIMEOUT_MS_DEFAULT: f64 = 5000.0;

/// `action_msgs/msg/GoalStatus` codes.
const STATUS_SUCCEEDED: i64 = 4;
const STATUS_CANCELED: i64 = 5;
const STATUS_ABORTED: i64 = 6;
/// `action_msgs/srv/CancelGoal` return codes.
const CANCEL_ERROR_NONE: i64 = 0;
const CANCEL_REJECTED: i64 = 1;
const CANCEL_UNKNOWN_GOAL: i64 = 2;
const CANCEL_GOAL_TERMINATED: i64 = 3;

/// The parameters both skills share.
struct Common {
    name: String,
    type_name: String,
    timeout: Duration,
    literal: Option<Literal>,
}

fn common(params: &BTreeMap<String, Param>, skill: &str, name_key: &str, literal_key: &str) -> Result<Common, String> {
    let text = |k: &str| params.get(k).and_then(Param::as_str);
    let needs = |key: &str, example: &str| format!("the {skill} skill needs `{key} := '{example}'`");
    let name = text(name_key).ok_or_else(|| needs(name_key, "/name"))?.to_string();
    let type_name = text("type").ok_or_else(|| needs("type", "package/kind/Name"))?.to_string();
    let timeout_ms = params.get("timeout_ms").and_then(Param::as_f64).unwrap_or(TIMEOUT_MS_DEFAULT);
    if !(1.0..=86_400_000.0).contains(&timeout_ms) {
        return Err(format!("`timeout_ms` must be between 1 and 86400000, not {timeout_ms}"));
    }
    let literal = match text(literal_key) {
        Some(text) => Some(literal::parse(text).map_err(|e| format!("`{literal_key}` cannot be read: {e}"))?),
        None => None,
    };
    Ok(Common { name, type_name, timeout: Duration::from_millis(timeout_ms as u64), literal })
}

/// Writes the parts of `value` that the `key` mappings name (their paths are relative to `value`).
fn write_outputs(call: &SkillCall, key: &str, value: &RosValue) -> Result<(), String> {
    for (i, path) in outputs_of(&call.outputs, key) {
        let v = value.value_at(path).map_err(|e| format!("`{key}`: {e}"))?;
        call.ctx.write(i, v);
    }
    Ok(())
}

/// A service call's parameters, its type and its request encoded: where checking and calling both start.
fn service_request(
    ros2: &Ros2,
    params: &BTreeMap<String, Param>,
) -> Result<(Common, Arc<ServiceType>, Vec<u8>), String> {
    let p = common(params, "ros2_service", "service", "request")?;
    let service = ros2.lib.service(&p.type_name)?;
    let request = cdr::encode(&ros2.lib, &service.request, p.literal.as_ref()).map_err(|e| format!("request: {e}"))?;
    Ok((p, service, request))
}

/// An action's parameters, its type and its goal, checked against the type: where checking and sending both
/// start. (Sending encodes the goal again, inside the SendGoal request with its id.)
fn action_goal(ros2: &Ros2, params: &BTreeMap<String, Param>) -> Result<(Common, Arc<ActionType>, Literal), String> {
    let p = common(params, "ros2_action", "action", "goal")?;
    let action = ros2.lib.action(&p.type_name)?;
    let goal = p.literal.clone().unwrap_or(Literal::Struct(Vec::new()));
    cdr::encode(&ros2.lib, &action.goal, Some(&goal)).map_err(|e| format!("goal: {e}"))?;
    Ok((p, action, goal))
}

/// `{skill := 'ros2_service', service := '/gripper/close', type := 'std_srvs/srv/SetBool', request := '(data :=
/// TRUE)', fault_if_false := 'success', response := 'message => text', timeout_ms := 5000}`.
pub struct Ros2Service {
    pub ros2: Arc<Ros2>,
}

impl Skill for Ros2Service {
    fn check(&self, params: &BTreeMap<String, Param>) -> Result<(), String> {
        service_request(&self.ros2, params).map(|_| ())
    }

    fn start(&self, call: SkillCall) -> SkillFuture {
        let ros2 = Arc::clone(&self.ros2);
        Box::pin(async move {
            let (p, service, request) = service_request(&ros2, &call.params)?;
            let deadline = Instant::now() + p.timeout;
            let node = ros2.node(&call.session).await?;
            let client = node.endpoint(Kind::Client, &p.name, &service.wire, keys::SERVICE_QOS).await?;
            node.wait_for(Kind::Service, &p.name, &service.wire, false, deadline).await?;
            let left = deadline.saturating_duration_since(Instant::now());
            let bytes = node.call(&p.name, &service, &client, request, Some(left)).await?;
            let response = cdr::decode(&ros2.lib, &service.response, &bytes).map_err(|e| format!("{}: {e}", p.name))?;
            write_outputs(&call, "response", &response)?;
            if let Some(field) = call.text("fault_if_false") {
                let path = [literal::PathPart::Field(field.to_string())];
                match response.value_at(&path) {
                    Ok(Value::Bool(true)) => {}
                    Ok(Value::Bool(false)) => {
                        let said = response
                            .value_at(&[literal::PathPart::Field("message".into())])
                            .ok()
                            .map(|m| m.as_str().to_string())
                            .filter(|m| !m.is_empty())
                            .map_or(String::new(), |m| format!(": {m}"));
                        return Err(format!("{} answered {field} = FALSE{said}", p.name));
                    }
                    Ok(other) => {
                        return Err(format!("`fault_if_false` names `{field}`, which is not a bool ({other})"))
                    }
                    Err(e) => return Err(format!("`fault_if_false`: {e}")),
                }
            }
            Ok(())
        })
    }
}

/// `{skill := 'ros2_action', action := '/arm/move_to', type := 'example_interfaces/action/Fibonacci', goal :=
/// '(order := 5)', result := 'sequence[4] => last', feedback := 'sequence[1] => partial', timeout_ms := 5000}`.
pub struct Ros2Action {
    pub ros2: Arc<Ros2>,
}

impl Skill for Ros2Action {
    fn check(&self, params: &BTreeMap<String, Param>) -> Result<(), String> {
        action_goal(&self.ros2, params).map(|_| ())
    }

    fn start(&self, call: SkillCall) -> SkillFuture {
        let ros2 = Arc::clone(&self.ros2);
        Box::pin(async move { run_action(&ros2, &call).await })
    }

    fn stops_itself(&self) -> bool {
        true
    }
}

/// A goal id as a literal of `unique_identifier_msgs/UUID`.
fn goal_id(uuid: &[u8; 16]) -> Literal {
    let bytes = uuid.iter().map(|&b| Literal::Scalar(Value::Int(b as i64))).collect();
    Literal::Struct(vec![("uuid".into(), Literal::Array(bytes))])
}

fn same_goal(message: &RosValue, uuid: &[u8; 16]) -> bool {
    let Some(RosValue::List(bytes)) =
        message.at(&[literal::PathPart::Field("goal_id".into()), literal::PathPart::Field("uuid".into())])
    else {
        return false;
    };
    bytes.len() == 16 && bytes.iter().zip(uuid).all(|(b, u)| *b == RosValue::UInt(*u as u64))
}

fn int_at(v: &RosValue, field: &str) -> i64 {
    v.value_at(&[literal::PathPart::Field(field.into())]).map_or(-1, |v| v.as_i64())
}

/// Runs `stage` unless the action ends first: `None` then, and nothing more may be asked of the server.
async fn unless_stopped<T>(call: &SkillCall, stage: impl std::future::Future<Output = T>) -> Option<T> {
    if call.ctx.is_stopped() {
        return None;
    }
    tokio::select! {
        biased;
        () = call.ctx.stopped() => None,
        out = stage => Some(out),
    }
}

async fn run_action(ros2: &Ros2, call: &SkillCall) -> Result<(), String> {
    // The goal is checked against its type before anything is sent.
    let (p, action, goal) = action_goal(ros2, &call.params)?;
    let lib = &ros2.lib;
    let uuid = *uuid::Uuid::new_v4().as_bytes();
    let request = cdr::encode_with(lib, &action.send_goal.request, vec![("goal_id", goal_id(&uuid)), ("goal", goal)])?;
    let deadline = Instant::now() + p.timeout;
    let sub_name = |s: &str| format!("{}/_action/{s}", p.name.trim_end_matches('/'));
    let (send_goal, get_result, cancel_goal, feedback) =
        (sub_name("send_goal"), sub_name("get_result"), sub_name("cancel_goal"), sub_name("feedback"));
    // Until the goal is sent, an action that ended (its step was left, or the agent fenced) asks nothing of the
    // server: the stop is checked before every stage, and a stage still waiting (for the server to appear, say)
    // is given up.
    let stopped_early = || Ok(());
    let Some(node) = unless_stopped(call, ros2.node(&call.session)).await else { return stopped_early() };
    let node = node?;
    let prepared = unless_stopped(call, async {
        let goal_client = node.endpoint(Kind::Client, &send_goal, &action.send_goal.wire, keys::SERVICE_QOS).await?;
        let result_client =
            node.endpoint(Kind::Client, &get_result, &action.get_result.wire, keys::SERVICE_QOS).await?;
        let cancel_client =
            node.endpoint(Kind::Client, &cancel_goal, &action.cancel_goal.wire, keys::SERVICE_QOS).await?;
        let (feedback_wire, _) = &action.feedback_message;
        // Subscribed before the goal is sent, so the first feedback is not missed.
        let feedback = node.subscription(&feedback, feedback_wire).await?;
        let announced = node.announce_action_client(&p.name, &action).await?;
        Ok::<_, String>((goal_client, result_client, cancel_client, feedback, announced))
    })
    .await;
    let Some(prepared) = prepared else { return stopped_early() };
    let (goal_client, result_client, cancel_client, (_feedback_endpoint, feedback_sub), _announced) = prepared?;
    let (_, feedback_def) = &action.feedback_message;
    let Some(cancel_service) = unless_stopped(call, node.wait_for_action(&p.name, &action, deadline)).await else {
        return stopped_early();
    };
    let cancel_service = cancel_service?;
    if call.ctx.is_stopped() {
        return stopped_early();
    }
    // Sent: from here on a stop cancels the goal once the server has answered whether it took it.
    let left = deadline.saturating_duration_since(Instant::now());
    let bytes = node.call(&send_goal, &action.send_goal, &goal_client, request, Some(left)).await?;
    let accepted = cdr::decode(lib, &action.send_goal.response, &bytes).map_err(|e| format!("{send_goal}: {e}"))?;
    if accepted.value_at(&[literal::PathPart::Field("accepted".into())]) != Ok(Value::Bool(true)) {
        return Err(format!("the server of {} rejected the goal", p.name));
    }
    let result_request = cdr::encode_with(lib, &action.get_result.request, vec![("goal_id", goal_id(&uuid))])?;
    let result = node.call(&get_result, &action.get_result, &result_client, result_request, None);
    tokio::pin!(result);
    let stopped = call.ctx.stopped();
    tokio::pin!(stopped);
    loop {
        tokio::select! {
            biased;
            bytes = &mut result => {
                let answer = cdr::decode(lib, &action.get_result.response, &bytes?).map_err(|e| format!("{get_result}: {e}"))?;
                return match int_at(&answer, "status") {
                    STATUS_SUCCEEDED => {
                        let part = answer.at(&[literal::PathPart::Field("result".into())]).cloned().unwrap_or(RosValue::Msg(String::new(), Vec::new()));
                        write_outputs(call, "result", &part)
                    }
                    STATUS_ABORTED => Err(format!("the server of {} aborted the goal", p.name)),
                    STATUS_CANCELED => Err(format!("the server of {} cancelled the goal", p.name)),
                    other => Err(format!("the server of {} ended the goal with status {other}", p.name)),
                };
            }
            () = &mut stopped => {
                return cancel(lib, &node, &cancel_service, &cancel_goal, &cancel_client, &uuid, p.timeout, &mut result).await;
            }
            sample = feedback_sub.recv_async() => {
                let Ok(sample) = sample else { continue };
                let bytes = sample.payload().to_bytes();
                // Feedback of another goal, or that does not decode, is not this goal's.
                let Ok(message) = cdr::decode(lib, feedback_def, &bytes) else { continue };
                if same_goal(&message, &uuid) {
                    if let Some(part) = message.at(&[literal::PathPart::Field("feedback".into())]) {
                        write_outputs(call, "feedback", part)?;
                    }
                }
            }
        }
    }
}

/// Cancels the goal and waits for the server to say so: its answer to the cancel request, then the goal's end.
#[allow(clippy::too_many_arguments)]
async fn cancel(
    lib: &Interfaces,
    node: &Node,
    service: &ServiceType,
    cancel_goal: &str,
    client: &super::client::Endpoint,
    uuid: &[u8; 16],
    timeout: Duration,
    result: &mut (impl std::future::Future<Output = Result<Vec<u8>, String>> + Unpin),
) -> Result<(), String> {
    let info = Literal::Struct(vec![("goal_id".into(), goal_id(uuid))]);
    let request = cdr::encode_with(lib, &service.request, vec![("goal_info", info)])?;
    let bytes = node.call(cancel_goal, service, client, request, Some(timeout)).await?;
    let answer = cdr::decode(lib, &service.response, &bytes).map_err(|e| format!("{cancel_goal}: {e}"))?;
    match int_at(&answer, "return_code") {
        CANCEL_ERROR_NONE => {}
        CANCEL_GOAL_TERMINATED => return Ok(()),
        CANCEL_REJECTED => return Err("the server refused to cancel the goal".to_string()),
        CANCEL_UNKNOWN_GOAL => return Err("the server does not know the goal any more".to_string()),
        other => return Err(format!("the server answered the cancel with code {other}")),
    }
    // The server accepted to cancel: the goal ends (cancelled, or finished meanwhile) soon after.
    match tokio::time::timeout(timeout, result).await {
        Ok(Ok(_)) => Ok(()),
        Ok(Err(e)) => Err(e),
        Err(_) => {
            Err(format!("the server accepted the cancel but the goal had not ended {} ms later", timeout.as_millis()))
        }
    }
}
