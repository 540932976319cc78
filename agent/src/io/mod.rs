//! The agent's end of chart variables bound to devices (`baton_proto::cluster::bindings`): for each run, one task per
//! connection — a Zenoh key (`keys`), a ROS 2 topic (`topics`), the OPC UA server of an endpoint (`nodes`) —
//! that turns the device's samples into values of the chart, sends the chart's outputs to the device, and says
//! whether the device can be reached.
//!
//! Both ways coalesce: an output's task sends the latest value when it is free again (a PLC writes its output
//! image once per scan, not every intermediate value), and the inputs that came while the agent's loop was busy
//! are taken together, the latest of each. So a device that floods the agent, or one that answers slowly,
//! costs a bounded amount of memory and work: one value per binding.

pub mod nodes;
mod shared;
pub mod topics;
pub mod zenoh_keys;

use std::collections::BTreeMap;
use std::sync::Arc;

use baton_proto::cluster::bindings::{IoBinding, IoDir, IoKind};
use baton_proto::types::Value;
use tokio::task::JoinHandle;
use zenoh::Session;

use crate::connections::Connections;

pub use shared::{Arrived, Latest, Sink};

/// The device connections of one run on this agent; dropped with the run, which ends them.
pub struct Devices {
    tasks: Vec<JoinHandle<()>>,
    outputs: BTreeMap<usize, Arc<Latest>>,
    pub sink: Sink,
}

impl Drop for Devices {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

impl Devices {
    /// Connects the bindings `here` (index in `Layout::io`, binding), with the agent's `connections`.
    pub fn start<'a>(
        session: &Session,
        connections: &Connections,
        here: impl Iterator<Item = (usize, &'a IoBinding)>,
        sink: Sink,
    ) -> Devices {
        let mut devices = Devices { tasks: Vec::new(), outputs: BTreeMap::new(), sink: sink.clone() };
        let mut servers: BTreeMap<String, Vec<(usize, IoBinding)>> = BTreeMap::new();
        for (i, b) in here {
            match (b.kind, b.dir) {
                (IoKind::Zenoh, IoDir::Input) => {
                    devices.tasks.push(tokio::spawn(zenoh_keys::input(session.clone(), i, b.clone(), sink.clone())));
                }
                (IoKind::Zenoh, IoDir::Output) => {
                    let latest = devices.output(i);
                    devices.tasks.push(tokio::spawn(zenoh_keys::output(
                        session.clone(),
                        i,
                        b.clone(),
                        latest,
                        sink.clone(),
                    )));
                }
                (IoKind::Ros2, dir) => {
                    let Some(ros2) = connections.ros2() else {
                        sink.state(i, Err("this agent was built without ROS 2 (Connections::with_ros2)".into()));
                        continue;
                    };
                    let task = match dir {
                        IoDir::Input => {
                            tokio::spawn(topics::input(Arc::clone(ros2), session.clone(), i, b.clone(), sink.clone()))
                        }
                        IoDir::Output => {
                            let latest = devices.output(i);
                            tokio::spawn(topics::output(
                                Arc::clone(ros2),
                                session.clone(),
                                i,
                                b.clone(),
                                latest,
                                sink.clone(),
                            ))
                        }
                    };
                    devices.tasks.push(task);
                }
                (IoKind::OpcUa, _) => {
                    if connections.opcua().is_none() {
                        sink.state(i, Err("this agent was built without OPC UA (Connections::with_opcua)".into()));
                        continue;
                    }
                    servers.entry(nodes::server_key(b)).or_default().push((i, b.clone()));
                }
            }
        }
        // One session per server (endpoint, security and user), for all the nodes bound on it.
        for (_, bindings) in servers {
            let latest = Arc::new(Latest::default());
            for (i, b) in &bindings {
                if b.dir == IoDir::Output {
                    devices.outputs.insert(*i, Arc::clone(&latest));
                }
            }
            let opcua = Arc::clone(connections.opcua().expect("checked above"));
            devices.tasks.push(tokio::spawn(nodes::server(opcua, bindings, latest, sink.clone())));
        }
        devices
    }

    fn output(&mut self, binding: usize) -> Arc<Latest> {
        Arc::clone(self.outputs.entry(binding).or_default())
    }

    /// Sends `value` to output `binding`'s device (the latest value wins if the device is busy).
    pub fn write(&self, binding: usize, value: Value) {
        if let Some(latest) = self.outputs.get(&binding) {
            latest.set(binding, value);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn a_sink_wakes_once_for_what_piles_up_and_keeps_the_latest() {
        let wakes = Arc::new(AtomicUsize::new(0));
        let counted = Arc::clone(&wakes);
        let sink = Sink::new(move || {
            counted.fetch_add(1, Ordering::Relaxed);
        });
        for i in 0..1000 {
            sink.value(0, Value::Int(i));
        }
        sink.state(1, Err("down".into()));
        sink.state(1, Ok(()));
        assert_eq!(wakes.load(Ordering::Relaxed), 1);
        let arrived = sink.take();
        assert_eq!(arrived.values.into_iter().collect::<Vec<_>>(), vec![(0, Value::Int(999))]);
        assert_eq!(arrived.states.get(&1), Some(&Ok(())));
        sink.value(0, Value::Int(5));
        assert_eq!(wakes.load(Ordering::Relaxed), 2, "emptied, the next sample wakes the loop again");
    }

    #[tokio::test]
    async fn outputs_waiting_are_replaced_by_newer_values() {
        let latest = Latest::default();
        latest.set(3, Value::Bool(true));
        latest.set(3, Value::Bool(false));
        latest.set(4, Value::Int(1));
        let got = latest.next().await;
        assert_eq!(got.into_iter().collect::<Vec<_>>(), vec![(3, Value::Bool(false)), (4, Value::Int(1))]);
    }
}
