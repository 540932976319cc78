//! Time: the agent's cycles on the run's grid, caught up after a stall, what is sent again, and the lease fence — no
//! contact with the router for too long, and the tokens that may go elsewhere are stopped.

use crate::cluster::runtime::agent::tokens::action_token;
use crate::cluster::runtime::Level;
use crate::cluster::wire::{AgentEventKind, TokenId};
use crate::exec::program::ActionId;
use crate::limits::CATCH_UP_CYCLES_MAX;

use super::{AgentOutput, AgentRun, RESEND_FIRST_MS, RESEND_MAX_MS};

impl AgentRun {
    /// Runs the cycles due by `now_ms`, each at its grid time, before anything that arrived at `now_ms` is
    /// applied. A host that could not keep up (the process was stopped) skips to the grid point before
    /// `now_ms` past `CATCH_UP_CYCLES_MAX` missed cycles, rather than running them back to back.
    pub(super) fn catch_up(&mut self, now_ms: u64) {
        while let Some(due) = self.next_cycle_ms.filter(|&t| t <= now_ms) {
            let at =
                if now_ms - due > CATCH_UP_CYCLES_MAX * self.cycle_ms { self.engine.grid_floor(now_ms) } else { due };
            self.advance(at);
            if let Err(e) = self.engine.handle_cycle(at) {
                self.log(Level::Error, format!("cycle refused: {e}"));
            }
            self.drain_engine();
            self.next_cycle_ms = self.engine.needs_cycle().then_some(at + self.cycle_ms);
        }
        self.advance(now_ms);
    }

    /// After an input: the engine reacts at once, the next cycle is planned if one is needed, and the news
    /// is reported.
    pub(super) fn settle(&mut self) {
        if let Err(e) = self.engine.react(self.now_ms) {
            self.log(Level::Error, format!("reaction refused: {e}"));
        }
        self.drain_engine();
        if self.next_cycle_ms.is_none() && self.engine.needs_cycle() {
            // The first cycle planned starts the grid here: otherwise the engine would floor times to the
            // millisecond while cycles run every cycle_ms, and a token arriving between two of them would
            // count its step's time, and start its timers, off the grid its cycles run on.
            if !self.grid_set {
                self.engine.set_grid(self.now_ms, self.cycle_ms);
                self.grid_set = true;
            }
            self.next_cycle_ms = Some(self.engine.grid_floor(self.now_ms) + self.cycle_ms);
        }
        self.report();
    }

    /// An agent with no cycle planned starts its grid when a token arrives: its first cycle runs at once. Nothing
    /// active here depends on the grid's phase then (otherwise a cycle would be planned).
    pub(super) fn anchor_grid(&mut self) {
        if self.next_cycle_ms.is_some() {
            return;
        }
        self.engine.set_grid(self.now_ms, self.cycle_ms);
        self.grid_set = true;
        if let Err(e) = self.engine.handle_cycle(self.now_ms) {
            self.log(Level::Error, format!("cycle refused: {e}"));
        }
        self.drain_engine();
        self.next_cycle_ms = Some(self.now_ms + self.cycle_ms);
    }

    /// When this run next needs `handle_timeout`: its next cycle, or the next report to send again.
    pub fn poll_timeout(&self) -> Option<u64> {
        let resend = self.tokens.values().flat_map(|t| t.unacked.iter().map(|u| u.resend_at_ms)).min();
        [self.next_cycle_ms, resend, self.vars_resend.at_ms()].into_iter().flatten().min()
    }

    /// Time passed: the cycles due run, reports due are sent again.
    pub fn handle_timeout(&mut self, now_ms: u64) {
        self.catch_up(now_ms);
        self.report();
        self.resend(now_ms, false);
        self.resend_vars();
    }

    pub(super) fn resend(&mut self, now_ms: u64, all: bool) {
        self.advance(now_ms);
        let mut again = Vec::new();
        for held in self.tokens.values_mut() {
            for u in held.unacked.iter_mut() {
                if all || u.resend_at_ms <= now_ms {
                    u.backoff_ms = (u.backoff_ms * 2).min(RESEND_MAX_MS);
                    u.resend_at_ms = now_ms + u.backoff_ms;
                    again.push(u.report.clone());
                }
            }
        }
        again.sort_by_key(|r| (r.token, r.seq));
        self.outbox.extend(again.into_iter().map(AgentOutput::Report));
    }

    /// The coordinator started again from its journal: every unacknowledged report goes now, and the delays
    /// start again from the first.
    pub fn handle_sync(&mut self, now_ms: u64) {
        // What it took from this agent before it died may not have been durable: it hears every value again.
        self.republish();
        for held in self.tokens.values_mut() {
            for u in held.unacked.iter_mut() {
                u.backoff_ms = RESEND_FIRST_MS / 2;
            }
        }
        self.resend(now_ms, true);
    }

    /// Why the skills of `token` may not run now: the agent lost its router and the token may be given to
    /// another agent.
    pub(super) fn fence_of(&self, token: Option<TokenId>) -> Option<String> {
        let silent_ms = self.fenced?;
        let fenced = token.and_then(|t| self.tokens.get(&t)).is_some_and(|h| h.fence);
        fenced.then(|| {
            format!(
                "the agent had no contact with its router for {silent_ms} ms, and the token may go to another agent (lease fence)"
            )
        })
    }

    /// The host's watch on the router: `Some(silent_ms)` once the agent has not heard its router for a quarter of
    /// its lease (`limits::fence_after_ms`), `None` when it hears it again. While fenced, the skills of tokens the
    /// coordinator may give to another agent are cancelled and none starts: each is reported as a skill fault,
    /// which reaches the coordinator when the link is back (and is stale there if the token moved).
    pub fn handle_contact(&mut self, now_ms: u64, lost: Option<u64>) {
        self.catch_up(now_ms);
        match (std::mem::replace(&mut self.fenced, lost), lost) {
            (None, Some(_)) => {}
            (Some(_), None) => {
                self.log(Level::Info, "the router is back: skills start again".to_string());
                // Updates published while the link was down may be lost: every reader hears them again.
                self.republish();
                return self.settle();
            }
            _ => return,
        }
        let mut stopped: Vec<ActionId> = self.running_skills.iter().copied().collect();
        stopped.sort_unstable();
        for a in stopped {
            let token = action_token(&self.action_segments, &self.by_segment, a);
            let Some(why) = self.fence_of(token) else { continue };
            self.running_skills.remove(&a);
            self.outbox.push_back(AgentOutput::StopSkill { action: a });
            self.set_indicators(a, Some(false), Some(true));
            self.say_cancelled(Level::Warn, a, &why);
            self.record(token, AgentEventKind::SkillFault { action: a.0, message: format!("cancelled: {why}") });
        }
        self.settle();
    }
}
