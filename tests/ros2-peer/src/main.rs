//! A ROS 2 action server for Baton's tests, written with hiroz (ZettaScale's ROS 2 over Zenoh, interoperable
//! with rmw_zenoh), so that Baton's own rmw_zenoh client is checked against an implementation it did not write.
//! It serves example_interfaces/action/Fibonacci under a name, behaving as the mode says, and prints one line
//! per protocol event on stdout for the test to read:
//!
//!     ros2-peer ENDPOINT DOMAIN NAME MODE
//!
//! MODE: `succeed` (a feedback per term, then the sequence), `reject`, `abort` (after the first feedback), or
//! `slow` (a term every 200 ms until cancelled, then cancelled).

use std::time::Duration;

use hiroz::action::messages::CancelGoalServiceResponse;
use hiroz::context::ZContextBuilder;
use hiroz::Builder;
use hiroz_msgs::example_interfaces::{action::Fibonacci, FibonacciFeedback, FibonacciResult};
use tokio::io::AsyncReadExt;

fn say(line: &str) {
    println!("{line}");
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, endpoint, domain, name, mode] = args.as_slice() else {
        return Err("usage: ros2-peer ENDPOINT DOMAIN NAME MODE".into());
    };
    let ctx = ZContextBuilder::default()
        .disable_multicast_scouting()
        .with_connect_endpoints([endpoint.as_str()])
        .with_domain_id(domain.parse()?)
        .build()?;
    let node = ctx.create_node("fibonacci_server").build()?;
    let server = node.create_action_server::<Fibonacci>(name).build()?;
    let mode = mode.clone();
    // Manual mode: hiroz 0.2.1's automatic driver answers no cancel while a result request waits (it awaits
    // the result inside its event loop), and a client asks for the result as soon as its goal is accepted.
    let cancels = server.clone();
    tokio::spawn(async move {
        while let Ok((request, query)) = cancels.recv_cancel_request_low().await {
            let known = cancels.request_cancel(request.goal_info.goal_id);
            say(if known { "CANCEL REQUESTED" } else { "CANCEL OF AN UNKNOWN GOAL" });
            let response = CancelGoalServiceResponse {
                return_code: if known { 0 } else { 2 },
                goals_canceling: if known { vec![request.goal_info] } else { vec![] },
            };
            let bytes = <CancelGoalServiceResponse as hiroz::msg::ZMessage>::serialize(&response);
            let mut reply = query.reply(query.key_expr().clone(), bytes);
            if let Some(attachment) = query.attachment() {
                reply = reply.attachment(attachment.clone());
            }
            if let Err(e) = reply.await {
                say(&format!("CANCEL REPLY FAILED {e}"));
            }
        }
    });
    let goals = server.clone();
    tokio::spawn(async move {
        while let Ok(goal) = goals.recv_goal().await {
            say(&format!("GOAL order={}", goal.goal().order));
            if mode == "reject" {
                let _ = goal.reject();
                say("REJECTED");
                continue;
            }
            let goal = goal.accept().execute();
            let mode = mode.clone();
            tokio::spawn(async move {
                let order = goal.goal().order;
                let mut sequence = vec![0, 1];
                let step = if mode == "slow" { Duration::from_millis(200) } else { Duration::from_millis(20) };
                let mut i = 2;
                loop {
                    if goal.is_cancel_requested() {
                        let _ = goal.canceled(FibonacciResult { sequence });
                        say("CANCELED");
                        return;
                    }
                    if mode != "slow" && i > order {
                        break;
                    }
                    let next = sequence[sequence.len() - 1].saturating_add(sequence[sequence.len() - 2]);
                    sequence.push(next);
                    let _ = goal.publish_feedback(FibonacciFeedback { sequence: sequence.clone() });
                    say(&format!("FEEDBACK {}", sequence.len()));
                    if mode == "abort" {
                        let _ = goal.abort(FibonacciResult { sequence });
                        say("ABORTED");
                        return;
                    }
                    i += 1;
                    tokio::time::sleep(step).await;
                }
                let _ = goal.succeed(FibonacciResult { sequence });
                say("SUCCEEDED");
            });
        }
    });
    say("READY");
    // Serve until the test closes stdin.
    let _ = tokio::io::stdin().read(&mut [0u8; 1]).await;
    Ok(())
}
