//! Time: the run's cycles on their grid, the next deadline (`poll_timeout`), and what falls due — dispatches sent
//! again, silent agents given up on, reassignments.

use std::collections::BTreeSet;

use crate::cluster::runtime::packml::State;
use crate::cluster::runtime::Level;
use crate::cluster::wire::TokenId;
use crate::limits::ACK_DELAY_MS;

use super::{CoordOutput, Coordinator, ASK_FIRST_MS, ASK_MAX_MS, DISPATCH_RESEND_MAX_MS};

impl Coordinator {
    /// The run's cycle period: the grid the host runs cycles on, and from which steps made active between
    /// cycles count their time.
    pub fn set_cycle_ms(&mut self, cycle_ms: u64) {
        self.cycle_ms = cycle_ms.max(1);
        self.engine.set_grid(0, self.cycle_ms);
    }

    /// Runs one cycle at `now_ms` (a grid time), then what is due: dispatches sent again, agents given up,
    /// acknowledgements, changed variables. Returns whether it changed anything: a cycle that did not needs no
    /// record in a journal (the next input carries the time on).
    pub fn handle_cycle(&mut self, now_ms: u64) -> bool {
        self.advance(now_ms);
        let (mutations, outputs, recovering) = (self.engine.mutations(), self.outbox.len(), self.recovered_ms);
        // Idle (`--wait-start`), the chart has not started: no cycle runs until `start`; nor once the run ended.
        if self.chart_runs() {
            if let Err(e) = self.engine.handle_cycle(self.now_ms) {
                self.log(Level::Error, format!("cycle refused: {e}"));
            }
        }
        self.drain_engine();
        self.complete_if_done();
        let resent_to = self.resend_dispatches();
        self.ask_quiet_agents(resent_to);
        self.resend_holds();
        self.resend_overrun_acks();
        self.expire_shelves();
        self.resend_gates();
        self.lose_gone_agents();
        self.reassign_due();
        self.give_up_on_silent_agents();
        self.publish_vars();
        self.resend_vars();
        self.flush_acks(true);
        self.engine.mutations() != mutations || self.outbox.len() != outputs || self.recovered_ms != recovering
    }

    /// After an input: the engine reacts to it (first scans of steps that became active, transitions that read
    /// what changed), and what that changed leaves at once.
    pub(super) fn settle(&mut self) {
        if self.run_state == State::Idle {
            return;
        }
        if self.chart_runs() {
            if let Err(e) = self.engine.react(self.now_ms) {
                self.log(Level::Error, format!("reaction refused: {e}"));
            }
        }
        self.drain_engine();
        self.complete_if_done();
        self.publish_vars();
        self.flush_acks(false);
    }

    /// The grid time of the next cycle, for a host whose last cycle ran at `last_cycle_ms`: never two in one
    /// period, never before what the coordinator waits for (`poll_timeout`), none when nothing needs one.
    pub fn next_cycle_ms(&self, last_cycle_ms: Option<u64>) -> Option<u64> {
        let wanted = self.poll_timeout()?;
        let mut after = last_cycle_ms.map_or(0, |t| t + self.cycle_ms);
        if last_cycle_ms.is_some_and(|t| self.now_ms > t) {
            // An input since the last cycle was reacted to at once, standing for the cycle at its grid point (the
            // steps it made active count their time from there): the next cycle comes after that point, or a
            // step made active exactly on it would be scanned twice there.
            after = after.max(self.now_ms - self.now_ms % self.cycle_ms + self.cycle_ms);
        }
        Some(wanted.max(after).div_ceil(self.cycle_ms) * self.cycle_ms)
    }

    /// When the next cycle is needed: at once (the next grid time) when the engine needs one, else at the
    /// earliest deadline (a dispatch to send again, acknowledgements to send, an agent to give up on), or never.
    pub fn poll_timeout(&self) -> Option<u64> {
        if self.engine.needs_cycle() && self.chart_runs() {
            return Some(self.now_ms);
        }
        // A dispatch to send again (no report yet), or an agent to ask (reported, then quiet).
        let resend = self
            .tokens
            .values()
            .filter(|t| !t.paused && t.confirmed && t.agent.is_some())
            .map(|t| t.resend_at_ms)
            .min();
        let acks = (!self.acks.is_empty()).then_some(self.acks_since_ms + ACK_DELAY_MS);
        let give_up = self.recovered_ms.and_then(|since| {
            self.agents.values().filter(|a| a.recovering && a.alive).map(|a| since.saturating_add(a.lease_ms)).min()
        });
        let reassign = self.tokens.values().filter_map(|t| t.reassign_at_ms).min();
        [
            resend,
            acks,
            give_up,
            self.next_loss_ms(),
            reassign,
            self.vars_resend.at_ms(),
            self.next_hold_resend_ms(),
            self.next_overrun_ack_ms(),
            self.alarms.next_unshelve_ms(),
            self.next_gate_resend_ms(),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// After a restart from the journal, an agent that has not come back within its lease is lost, as if its
    /// liveliness token had gone: its tokens are paused, reassigned or fail the run.
    pub(super) fn give_up_on_silent_agents(&mut self) {
        let Some(since) = self.recovered_ms else { return };
        let now = self.now_ms;
        let silent: Vec<String> = self
            .agents
            .iter()
            .filter(|(_, a)| a.recovering && a.alive && now >= since.saturating_add(a.lease_ms))
            .map(|(n, _)| n.clone())
            .collect();
        for name in silent {
            self.log(Level::Warn, format!("agent `{name}` did not come back within its lease after the restart"));
            self.lose_agent(&name);
        }
        if self.agents.values().all(|a| !a.recovering || !a.alive) {
            self.recovered_ms = None;
        }
    }

    /// A dispatch lost on the way (a link that broke and came back within the agent's lease) would leave its
    /// segment waiting for ever: a dispatch that no report answered goes again, with doubling delays. The agent
    /// drops the copy if the first one arrived. Returns the agents sent to from the second time on (a token quiet
    /// for `ASK_FIRST_MS` and more): they are asked too (`ask_quiet_agents`), for a dispatch that did arrive and a
    /// report of it that did not. The first resend asks nothing: a motion is usually running then.
    pub(super) fn resend_dispatches(&mut self) -> BTreeSet<String> {
        let mut resent_to = BTreeSet::new();
        let now = self.now_ms;
        let mut due: Vec<TokenId> = self
            .tokens
            .iter()
            .filter(|(_, t)| t.next_seq == 0 && !t.paused && t.confirmed && t.resend_at_ms <= now)
            .filter(|(_, t)| t.agent.as_ref().and_then(|a| self.agents.get(a)).is_some_and(|a| a.alive))
            .map(|(id, _)| *id)
            .collect();
        due.sort_unstable();
        for id in due {
            self.publish_vars();
            let Some((agent, msg)) = self.dispatch_msg(id) else { continue };
            if let Some(t) = self.tokens.get_mut(&id) {
                if now.saturating_sub(t.dispatched_ms) >= ASK_FIRST_MS {
                    resent_to.insert(agent.clone());
                }
                t.resend_backoff_ms = (t.resend_backoff_ms * 2).min(DISPATCH_RESEND_MAX_MS);
                t.resend_at_ms = now + t.resend_backoff_ms;
            }
            self.stats.resent += 1;
            self.log(Level::Info, format!("token {id} sent again to `{agent}`: no report on it yet"));
            self.send(agent, msg);
        }
        resent_to
    }

    /// The agents of tokens that reported and then went quiet, and those a dispatch was just sent again to
    /// (`asked`), are asked for the reports they have not had acknowledged (`CoordOutput::Ask`), once per agent
    /// however many of its tokens are quiet, with doubling delays; a report on the token starts them over.
    pub(super) fn ask_quiet_agents(&mut self, mut asked: BTreeSet<String>) {
        let now = self.now_ms;
        for t in self.tokens.values_mut() {
            let live = t.agent.as_ref().and_then(|a| self.agents.get(a)).is_some_and(|a| a.alive);
            if t.next_seq == 0 || t.paused || !t.confirmed || !live || t.resend_at_ms > now {
                continue;
            }
            t.resend_backoff_ms = (t.resend_backoff_ms * 2).min(ASK_MAX_MS);
            t.resend_at_ms = now + t.resend_backoff_ms;
            asked.extend(t.agent.clone());
        }
        for agent in asked {
            let Some(a) = self.agents.get(&agent) else { continue };
            self.stats.asked += 1;
            self.outbox.push_back(CoordOutput::Ask { incarnation: a.incarnation, agent });
        }
    }

    /// Tokens of lost agents whose fence margin is over go to other agents.
    pub(super) fn reassign_due(&mut self) {
        let now = self.now_ms;
        let mut due: Vec<TokenId> = self
            .tokens
            .iter()
            .filter(|(_, t)| t.reassign_at_ms.is_some_and(|at| at <= now))
            .map(|(id, _)| *id)
            .collect();
        due.sort_unstable();
        for id in due {
            self.reassign(id);
        }
    }
}
