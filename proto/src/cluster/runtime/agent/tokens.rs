//! Tokens: a dispatch taken once per epoch, its segment run by the agent's engine, what happened reported (and sent
//! again until acknowledged), a join, a drop, and what finished.

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;

use crate::cluster::layout::SegmentId;
use crate::cluster::runtime::Level;
use crate::cluster::wire::{AgentEvent, AgentEventKind, Report, TokenId, VarValue};
use crate::exec::engine::{EventKind, RemoteInput};
use crate::exec::program::{ActionId, StepId, VarId};
use crate::exec::trace::fault_message;
use crate::limits::{FINISHED_TOKENS_REMEMBERED, REPORTS_UNACKED_MAX, REPORT_EVENTS_MAX};

use super::{AgentOutput, AgentRun, Dispatch, Holding, Join, Unacked, RESEND_FIRST_MS};

/// The token an action's event belongs to: that of the first segment using the action that has a token here.
pub(super) fn action_token(
    action_segments: &[Vec<SegmentId>],
    by_segment: &BTreeMap<SegmentId, TokenId>,
    a: ActionId,
) -> Option<TokenId> {
    action_segments.get(a.index())?.iter().find_map(|g| by_segment.get(g).copied())
}

impl AgentRun {
    /// A token arrives. A duplicate (same token and epoch, or an older epoch) or a token already finished in
    /// that epoch changes nothing; a newer epoch of a token dropped here runs.
    pub fn handle_dispatch(&mut self, now_ms: u64, d: Dispatch) {
        self.catch_up(now_ms);
        if self.aborted {
            return self.drop_msg(format!("dispatch of token {} refused: the run was aborted", d.token));
        }
        let seen = self.tokens.get(&d.token).map(|t| t.epoch).or_else(|| self.finished.get(&d.token).copied());
        if seen.is_some_and(|epoch| epoch >= d.epoch) {
            self.dropped += 1;
            return;
        }
        if self.tokens.contains_key(&d.token) {
            // A newer epoch of a token held here: the old one is over.
            self.forget(d.token);
        }
        let Some(segment) = self.layout.segments.get(d.segment as usize) else {
            return self.drop_msg(format!("dispatch of token {} names unknown segment {}", d.token, d.segment));
        };
        let g = SegmentId(d.segment);
        let entry = StepId(d.entry);
        if !segment.steps.contains(&entry) {
            return self.drop_msg(format!("dispatch of token {} enters its segment at a step outside it", d.token));
        }
        if !self.serves.contains(&segment.placement) {
            let p = segment.placement.to_string();
            return self.drop_msg(format!(
                "token {} dropped: its segment is placed on {p}, which `{}` does not serve",
                d.token, self.name
            ));
        }
        if let Some(other) = self.by_segment.get(&g) {
            let other = *other;
            return self
                .drop_msg(format!("token {} dropped: token {other} already runs the same segment here", d.token));
        }
        self.handle_peers_table(d.peers);
        self.take_coordinator_values(&d.vars, d.vars_seq);
        self.anchor_grid();
        if self.engine.is_active(entry) {
            return self.drop_msg(format!("token {} dropped: its entry step is already active here", d.token));
        }
        for s in self.layout.segments[g.index()].steps.clone() {
            self.engine.set_held(self.now_ms, s, d.held);
        }
        self.engine.set_mode(d.mode);
        if !d.held {
            if let Err(e) = self.engine.handle_remote(self.now_ms, RemoteInput::Activate(entry)) {
                return self.drop_msg(format!("token {} dropped: {e}", d.token));
            }
        }
        let held = Holding {
            epoch: d.epoch,
            fence: d.fence,
            segment: g,
            arrived_ms: self.now_ms,
            next_seq: 0,
            events: Vec::new(),
            done: false,
            unacked: VecDeque::new(),
            held: d.held,
            held_said: None,
            pending_entry: d.held.then_some(entry),
        };
        self.tokens.insert(d.token, held);
        self.by_segment.insert(g, d.token);
        self.settle();
    }

    /// The coordinator asks this agent to take part in the run: it restarted, or saw this agent come back. The
    /// join carries the run's values (a new process takes even its own) and writers; the coordinator hears again
    /// which devices are down (it may have missed the report) and every value this agent writes.
    pub fn handle_join(&mut self, now_ms: u64, join: Join) {
        self.catch_up(now_ms);
        self.handle_peers_table(join.peers);
        self.take_coordinator_values(&join.vars, join.vars_seq);
        if self.io_here().next().is_some() {
            self.report_devices();
        }
        self.republish();
        self.settle();
    }

    /// The coordinator took this token back (its segment went to another epoch): stop running it.
    pub fn handle_drop(&mut self, now_ms: u64, token: TokenId, epoch: u32) {
        self.catch_up(now_ms);
        if self.tokens.get(&token).is_some_and(|t| t.epoch == epoch) {
            self.log(Level::Warn, format!("token {token} epoch {epoch} dropped at the coordinator's request"));
            self.forget(token);
            self.settle();
        }
    }

    /// Deactivates what a token still holds here and forgets it; its actions stop in the next cycle.
    pub(super) fn forget(&mut self, token: TokenId) {
        let Some(held) = self.tokens.remove(&token) else { return };
        if self.by_segment.get(&held.segment) == Some(&token) {
            self.by_segment.remove(&held.segment);
        }
        for s in self.layout.segments[held.segment.index()].steps.clone() {
            if self.engine.is_active(s) {
                let _ = self.engine.handle_remote(self.now_ms, RemoteInput::Deactivate(s));
            }
            self.engine.set_held(self.now_ms, s, false);
        }
        self.remember_finished(token, held.epoch);
    }

    /// Remembers a finished token, to recognise a late duplicate of its dispatch; the oldest are forgotten.
    pub(super) fn remember_finished(&mut self, token: TokenId, epoch: u32) {
        if self.finished.insert(token, epoch).is_none() {
            if self.finished_order.len() >= FINISHED_TOKENS_REMEMBERED {
                if let Some(old) = self.finished_order.pop_front() {
                    self.finished.remove(&old);
                }
            }
            self.finished_order.push_back(token);
        }
    }

    /// The coordinator applied this token's reports up to `seq`.
    pub fn handle_ack(&mut self, token: TokenId, epoch: u32, seq: u32, done: bool) {
        let Some(held) = self.tokens.get_mut(&token) else { return };
        if held.epoch != epoch {
            return;
        }
        let full = held.unacked.len() >= REPORTS_UNACKED_MAX;
        while held.unacked.front().is_some_and(|u| u.report.seq <= seq) {
            held.unacked.pop_front();
        }
        if done && held.done && held.unacked.is_empty() {
            self.tokens.remove(&token);
            self.remember_finished(token, epoch);
        } else if full {
            // Room again: what waited leaves now.
            self.report();
        }
    }

    pub(super) fn drain_engine(&mut self) {
        let program = Arc::clone(&self.program);
        while let Some(ev) = self.engine.poll_event() {
            match ev.kind {
                EventKind::Fire(t) => {
                    let token = program
                        .sources(t)
                        .first()
                        .and_then(|s| self.layout.segment_of[s.index()])
                        .and_then(|g| self.by_segment.get(&g).copied());
                    self.record(token, AgentEventKind::Fire { transition: t.0 });
                }
                EventKind::ActionOn(a) => {
                    let token = action_token(&self.action_segments, &self.by_segment, a);
                    self.record(token, AgentEventKind::ActionOn { action: a.0 });
                    if let Some(binding) = self.layout.skills[a.index()].clone() {
                        if let Some(why) = self.fence_of(token) {
                            // The token may be running elsewhere by now: nothing moves here.
                            self.set_indicators(a, Some(false), Some(true));
                            let message = format!("not started: {why}");
                            self.record(token, AgentEventKind::SkillFault { action: a.0, message });
                            continue;
                        }
                        if self.skill_held(a) {
                            self.started_while_held += 1;
                        }
                        self.running_skills.insert(a);
                        self.skill_started.insert(a, self.now_ms);
                        let name = program.actions[a.index()].name.clone();
                        self.outbox.push_back(AgentOutput::StartSkill { action: a, name, binding });
                    }
                }
                EventKind::ActionOff(a) => {
                    let token = action_token(&self.action_segments, &self.by_segment, a);
                    self.record(token, AgentEventKind::ActionOff { action: a.0 });
                    if self.running_skills.remove(&a) {
                        self.outbox.push_back(AgentOutput::StopSkill { action: a });
                    }
                }
                EventKind::Fault(source, fault) => {
                    let message = fault_message(&program, source, fault);
                    let token = match source {
                        crate::exec::engine::FaultSource::Transition(t) => program
                            .sources(t)
                            .first()
                            .and_then(|s| self.layout.segment_of[s.index()])
                            .and_then(|g| self.by_segment.get(&g).copied()),
                        crate::exec::engine::FaultSource::Action(a) => {
                            action_token(&self.action_segments, &self.by_segment, a)
                        }
                    };
                    self.record(token, AgentEventKind::Fault { message });
                }
                EventKind::Overrun(s) => {
                    let token = self.layout.segment_of[s.index()].and_then(|g| self.by_segment.get(&g).copied());
                    let mut why = self.engine.take_overrun_why(s).unwrap_or_else(|| self.engine.why(s));
                    why.skills = self.skills_of(s);
                    self.record(token, AgentEventKind::Overrun { step: s.0, why: why.summary() });
                }
                EventKind::Activate(_) | EventKind::Deactivate(_) => {}
            }
        }
    }

    pub(super) fn record(&mut self, token: Option<TokenId>, kind: AgentEventKind) {
        let Some(token) = token else { return };
        let Some(held) = self.tokens.get_mut(&token) else { return };
        let dt_ms = self.now_ms.saturating_sub(held.arrived_ms);
        held.events.push(AgentEvent { dt_ms, kind });
    }

    /// Sends what happened since the last report: the changed variables this agent writes (published to every
    /// reader, and carried in the first report so that the coordinator sees them before the clearings they
    /// led to), then one report per token with news.
    ///
    /// A token has at most `REPORTS_UNACKED_MAX` reports out unacknowledged. Past that no report is numbered
    /// until acknowledgements make room: the events wait in order, the values coalesce (only the latest of each
    /// counts), and all of it leaves, in reports of at most `REPORT_EVENTS_MAX` events, once there is room. So
    /// whatever the coordinator has not acknowledged can always be sent again, however long it was away.
    pub(super) fn report(&mut self) {
        self.confirm_holds();
        self.report_waiting();
        self.send_outputs();
        let mut changed = Vec::new();
        for (i, &v) in self.owned.iter().enumerate() {
            let value = self.engine.value(v);
            if self.published[i] != value {
                self.published[i] = value.clone();
                changed.push(VarValue::new(v, value.clone()));
                self.unreported.insert(v.0, value);
            }
        }
        if !changed.is_empty() {
            self.vars_seq += 1;
            // Other agents get what their code reads; the coordinator gets everything, in the reports.
            let read: Vec<VarValue> =
                changed.iter().filter(|vv| self.layout.read_by_agents[vv.var as usize]).cloned().collect();
            if !read.is_empty() {
                self.publish(read);
            }
        }
        let mut ids: Vec<TokenId> = self.tokens.keys().copied().collect();
        ids.sort_unstable();
        for id in ids {
            let segment_active = {
                let held = &self.tokens[&id];
                held.pending_entry.is_some()
                    || self.layout.segments[held.segment.index()].steps.iter().any(|&s| self.engine.is_active(s))
            };
            let Some(held) = self.tokens.get_mut(&id) else { continue };
            while !held.done && held.unacked.len() < REPORTS_UNACKED_MAX {
                if held.events.is_empty() && segment_active && self.unreported.is_empty() {
                    break;
                }
                let events: Vec<AgentEvent> = held.events.drain(..held.events.len().min(REPORT_EVENTS_MAX)).collect();
                let done = !segment_active && held.events.is_empty();
                let vars =
                    std::mem::take(&mut self.unreported).into_iter().map(|(var, v)| VarValue::new(VarId(var), v));
                let report = Report {
                    run: self.run,
                    agent: self.name.clone(),
                    incarnation: self.incarnation,
                    token: id,
                    epoch: held.epoch,
                    seq: held.next_seq,
                    events,
                    vars: vars.collect(),
                    vars_seq: self.vars_seq,
                    done,
                };
                held.next_seq += 1;
                held.done = done;
                if done {
                    self.by_segment.remove(&held.segment);
                }
                held.unacked.push_back(Unacked {
                    report: report.clone(),
                    sent_ms: self.now_ms,
                    resend_at_ms: self.now_ms + RESEND_FIRST_MS,
                    backoff_ms: RESEND_FIRST_MS,
                });
                self.outbox.push_back(AgentOutput::Report(report));
            }
        }
    }
}
