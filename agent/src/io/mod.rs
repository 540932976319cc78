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
pub mod topics;
pub mod zenoh_keys;

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use baton_proto::cluster::bindings::{IoBinding, IoDir, IoKind};
use baton_proto::types::Value;
use tokio::sync::Notify;
use tokio::task::JoinHandle;
use zenoh::Session;

use crate::connections::Connections;

/// What the devices of a run gave since the agent last looked: per binding (`Layout::io` index), the latest
/// value of an input and the latest state of the connection (`Err` says why it cannot be reached).
#[derive(Debug, Default)]
pub struct Arrived {
    pub values: BTreeMap<usize, Value>,
    pub states: BTreeMap<usize, Result<(), String>>,
}

impl Arrived {
    fn is_empty(&self) -> bool {
        self.values.is_empty() && self.states.is_empty()
    }
}

/// Where a run's device tasks put what they learn; the agent's loop is woken once for whatever piled up.
#[derive(Clone)]
pub struct Sink {
    arrived: Arc<Mutex<Arrived>>,
    wake: Arc<dyn Fn() + Send + Sync>,
}

impl Sink {
    pub fn new(wake: impl Fn() + Send + Sync + 'static) -> Sink {
        Sink { arrived: Arc::default(), wake: Arc::new(wake) }
    }

    fn put(&self, f: impl FnOnce(&mut Arrived)) {
        let first = {
            let mut arrived = self.arrived.lock().expect("device sink");
            let first = arrived.is_empty();
            f(&mut arrived);
            first
        };
        if first {
            (self.wake)();
        }
    }

    /// A sample of input `binding`'s device.
    pub fn value(&self, binding: usize, value: Value) {
        self.put(|a| {
            a.values.insert(binding, value);
        });
    }

    /// Whether `binding`'s device can be reached.
    pub fn state(&self, binding: usize, state: Result<(), String>) {
        self.put(|a| {
            a.states.insert(binding, state);
        });
    }

    /// Everything that arrived since the last call.
    pub fn take(&self) -> Arrived {
        std::mem::take(&mut *self.arrived.lock().expect("device sink"))
    }
}

/// The latest values of outputs, waiting for their task: a newer value replaces one not sent yet.
#[derive(Default)]
pub struct Latest {
    values: Mutex<BTreeMap<usize, Value>>,
    notify: Notify,
}

impl Latest {
    pub fn set(&self, binding: usize, value: Value) {
        self.values.lock().expect("outputs").insert(binding, value);
        self.notify.notify_one();
    }

    /// Waits for values to send, and takes them all.
    pub async fn next(&self) -> BTreeMap<usize, Value> {
        loop {
            let values = std::mem::take(&mut *self.values.lock().expect("outputs"));
            if !values.is_empty() {
                return values;
            }
            self.notify.notified().await;
        }
    }
}

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

/// An output's next value to send: a new one from the chart, or, every `period_ms` if the binding has one, the
/// last one again.
pub(crate) struct Resend {
    binding: usize,
    last: Option<Value>,
    period: Option<tokio::time::Interval>,
}

impl Resend {
    pub(crate) fn new(binding: usize, period_ms: Option<u64>) -> Resend {
        let period = period_ms.map(|ms| {
            let mut t = tokio::time::interval(std::time::Duration::from_millis(ms.max(1)));
            t.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            t
        });
        Resend { binding, last: None, period }
    }

    pub(crate) async fn next(&mut self, latest: &Latest) -> Value {
        loop {
            let value = match self.period.as_mut() {
                Some(period) => tokio::select! {
                    values = latest.next() => values.get(&self.binding).cloned(),
                    _ = period.tick() => self.last.clone(),
                },
                None => latest.next().await.get(&self.binding).cloned(),
            };
            if let Some(v) = value {
                self.last = Some(v.clone());
                return v;
            }
        }
    }
}

/// How long a connection that failed waits before it tries again: doubling from the first to the last.
pub(crate) const RETRY_FIRST: std::time::Duration = std::time::Duration::from_millis(500);
pub(crate) const RETRY_MAX: std::time::Duration = std::time::Duration::from_secs(5);

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
