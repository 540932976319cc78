//! What a binding's device task and the agent share: the `Sink` its inputs arrive in (`Arrived`), the `Latest` value
//! an output writes, and when a write or a connection is tried again (`Resend`, `RETRY_FIRST`, `RETRY_MAX`).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use baton_proto::types::Value;
use tokio::sync::Notify;

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
