//! Step supervision across the run: a step active longer than its `max_ms` — in the coordinator's engine or on the
//! agent that runs it — raises a latched alarm; only that step's path waits (its outgoing transitions clear once the
//! alarm is acknowledged, except the chart's own recovery, which reads `S.overrun`), and the other branches go on.
//! An acknowledgement of an agent's step is carried to the agent (`ToAgent::AckOverrun`) and sent again until it
//! says it applied it. The alarm's cause is gone when the step is left; acknowledged and gone, it is back to normal.

use crate::cluster::runtime::alarms::{AlarmChange, AlarmId};
use crate::cluster::runtime::Level;
use crate::cluster::wire::{ToAgent, TokenId};
use crate::exec::program::StepId;
use crate::exec::trace::{overrun_message, TraceEvent, TraceRecord};
use crate::limits::ALARMS_STANDING_MAX;

use super::state::Supervised;
use super::Coordinator;

const ACK_RESEND_FIRST_MS: u64 = 200;
const ACK_RESEND_MAX_MS: u64 = 2_000;

impl Coordinator {
    /// A step passed its maximum time: a latched alarm, kept with the step (and the token on an agent).
    pub(super) fn on_overrun(
        &mut self,
        t_ms: u64,
        s: StepId,
        token: Option<(TokenId, u32)>,
        agent: Option<&str>,
        why: &str,
    ) {
        let step = self.program.steps[s.index()].name.clone();
        let mut message = overrun_message(&self.program, s);
        if let Some(a) = agent {
            message.push_str(&format!(" (on `{a}`)"));
        }
        // What it waited for at that moment stays with the alarm (S7-GRAPH's CRIT_FLT).
        if !why.is_empty() {
            message.push_str(&format!("; it waited for: {why}"));
        }
        let mut rec = TraceRecord::new(t_ms, TraceEvent::Alarm, &step);
        let supervised = Supervised { step: s, token, ack_resend_at_ms: None, ack_backoff_ms: 0 };
        if let Some(AlarmChange::Raised { id, .. }) = self.alarms.raise(self.now_ms, &step, &message, true) {
            rec.id = Some(id.0);
            self.supervised.insert(id, supervised);
        } else {
            // The list is full: an alarm nobody can see, nobody can acknowledge, so its step must not wait for
            // that. Said loudly, and acknowledged at once under a number no listed alarm has.
            message.push_str(&format!(
                "; not listed: {ALARMS_STANDING_MAX} alarms stand already (acknowledge some), so its step does not \
                 wait for an acknowledgement"
            ));
            let id = AlarmId(u64::MAX - self.alarms.refused);
            self.supervised.insert(id, supervised);
            self.supervision_acknowledged(id);
        }
        rec.agent = agent.map(str::to_string);
        rec.message = Some(message.clone());
        self.trace(rec);
        self.log(Level::Error, message);
    }

    /// An operator acknowledged alarm `id`: a supervision fault's step may go on.
    pub(super) fn supervision_acknowledged(&mut self, id: AlarmId) {
        let Some(sup) = self.supervised.get_mut(&id) else { return };
        match sup.token {
            None => {
                let s = sup.step;
                self.engine.acknowledge_overrun(s);
            }
            Some(_) => {
                sup.ack_resend_at_ms = Some(self.now_ms + ACK_RESEND_FIRST_MS);
                sup.ack_backoff_ms = ACK_RESEND_FIRST_MS;
                self.send_ack_overrun(id);
            }
        }
    }

    fn send_ack_overrun(&mut self, id: AlarmId) {
        let Some(Supervised { step, token: Some((token, epoch)), .. }) = self.supervised.get(&id) else { return };
        let (step, token, epoch) = (*step, *token, *epoch);
        let Some(agent) = self.tokens.get(&token).filter(|t| t.epoch == epoch).and_then(|t| t.agent.clone()) else {
            return;
        };
        self.send(agent, ToAgent::AckOverrun { run: self.run, token, epoch, step: step.0 });
    }

    /// The agent applied the acknowledgement of `step`'s fault.
    pub(super) fn overrun_acknowledged(&mut self, token: TokenId, step: StepId) {
        for sup in self.supervised.values_mut() {
            if sup.step == step && sup.token.is_some_and(|(t, _)| t == token) {
                sup.ack_resend_at_ms = None;
            }
        }
    }

    /// Acknowledgements not yet applied by their agent go again, with doubling delays.
    pub(super) fn resend_overrun_acks(&mut self) {
        let now = self.now_ms;
        let due: Vec<AlarmId> = self
            .supervised
            .iter()
            .filter(|(_, s)| s.ack_resend_at_ms.is_some_and(|t| t <= now))
            .map(|(id, _)| *id)
            .collect();
        for id in due {
            if let Some(s) = self.supervised.get_mut(&id) {
                s.ack_backoff_ms = (s.ack_backoff_ms * 2).min(ACK_RESEND_MAX_MS);
                s.ack_resend_at_ms = Some(now + s.ack_backoff_ms);
            }
            self.send_ack_overrun(id);
        }
    }

    pub(super) fn next_overrun_ack_ms(&self) -> Option<u64> {
        self.supervised.values().filter_map(|s| s.ack_resend_at_ms).min()
    }

    /// Step `s` was left: the cause of its supervision alarms is gone (acknowledged too, they are back to normal).
    pub(super) fn supervised_step_left(&mut self, s: StepId) {
        let ids: Vec<AlarmId> = self.supervised.iter().filter(|(_, sup)| sup.step == s).map(|(id, _)| *id).collect();
        for id in ids {
            self.supervised.remove(&id);
            let changes = self.alarms.cause_gone(id);
            self.alarm_changes(changes);
        }
    }
}
