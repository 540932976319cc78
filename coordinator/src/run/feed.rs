//! The run's trace, live, for consoles: every record is published on `keys::trace(run)` as it is made — dropped,
//! never waited for, when the network is slow (the run goes first; a console's next status query is the truth) —
//! and the run's history (commands, state and mode changes, alarms, faults, agents lost and back, inputs set) is
//! kept, the last `HISTORY_MAX` records, and answered on `keys::history(run)` to a console that joins a run under
//! way. A coordinator that takes a run over from its journal replays the records since the journal's last snapshot
//! through here: its history starts there.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use baton_host::{traffic, ZenohResult};
use baton_proto::cluster::keys;
use baton_proto::cluster::wire::{self, RunId};
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::query::Queryable;
use zenoh::Session;

/// History records kept: a shift's worth of commands and alarms, and well under a message's size limit.
pub const HISTORY_MAX: usize = 2000;

/// Whether a record belongs to the run's history, as an operator reads it (who did what, what the run did, what
/// went wrong) rather than its steps' coming and going.
pub fn is_history(event: TraceEvent) -> bool {
    use TraceEvent::*;
    matches!(
        event,
        Command
            | CommandRefused
            | State
            | Mode
            | Alarm
            | AlarmClear
            | Ack
            | Shelve
            | Unshelve
            | Fault
            | AgentUp
            | AgentLost
            | Set
            | Recover
            | NewRun
            | Withdraw
            | Told
            | DeviceDown
            | DeviceUp
    )
}

pub struct Feed {
    publisher: Publisher<'static>,
    history: Arc<Mutex<VecDeque<TraceRecord>>>,
    _answers: Queryable<()>,
}

impl Feed {
    /// Declares the run's trace publisher and its history queryable.
    pub async fn declare(session: &Session, run: RunId) -> anyhow::Result<Feed> {
        let publisher =
            traffic::publisher(session, keys::trace(run)).congestion_control(CongestionControl::Drop).await.zenoh()?;
        let history: Arc<Mutex<VecDeque<TraceRecord>>> = Arc::default();
        let kept = Arc::clone(&history);
        let key = keys::history(run);
        let answers = traffic::queryable(session, key.clone())
            .callback(move |query| {
                let records: Vec<TraceRecord> = match kept.lock() {
                    Ok(h) => h.iter().cloned().collect(),
                    Err(_) => return,
                };
                if let Err(e) = traffic::reply(&query, key.clone(), wire::encode(&records)) {
                    eprintln!("warning: cannot answer a history query: {e}");
                }
            })
            .await
            .zenoh()?;
        Ok(Feed { publisher, history, _answers: answers })
    }

    /// Publishes `rec`, and keeps it when it is history.
    pub fn record(&self, rec: &TraceRecord) {
        use zenoh::Wait;
        if is_history(rec.event) {
            if let Ok(mut h) = self.history.lock() {
                if h.len() == HISTORY_MAX {
                    h.pop_front();
                }
                h.push_back(rec.clone());
            }
        }
        // Dropped with the link congested: nothing of the run waits for a console.
        let _ = self.publisher.put(wire::encode(rec)).wait();
    }
}
