//! Reports: what an agent says it did with a token, admitted once and in order per token, mirrored in the coordinator's
//! engine, or refused as stale.

use std::sync::Arc;

use crate::cluster::layout::{Placement, SegmentId};
use crate::exec::program::Program;

use crate::cluster::runtime::Level;
use crate::cluster::wire::{AckEntry, AgentEventKind, Report, ToAgent};
use crate::exec::engine::RemoteInput;
use crate::exec::program::{StepId, TransitionId};
use crate::exec::trace::{TraceEvent, TraceRecord};
use crate::limits::{REPORTS_AHEAD_BYTES_MAX, REPORTS_AHEAD_MAX, STALE_EPOCHS_TRACED};

use super::{CoordOutput, Coordinator, ASK_FIRST_MS};

/// What a report from an agent would do (`Coordinator::classify_report`).
pub(super) enum ReportFate {
    OtherRun,
    /// A duplicate of a finished token's last report: acknowledged again.
    FinishedAgain(AckEntry),
    UnknownToken,
    /// Of an older epoch; `first` of its epoch to come.
    Stale {
        first: bool,
    },
    /// Of an epoch never dispatched.
    FutureEpoch,
    NotHolder,
    OtherProcess,
    /// Applied already: acknowledged again.
    Old,
    /// Ahead of a missing one: held if there is `room`.
    Ahead {
        room: bool,
    },
    /// The one the token waits for.
    Next,
}

impl Coordinator {
    /// What a report would do here; `handle_report` does it, and the journal records only those that change
    /// what a replay must rebuild (`admit_report`).
    pub(super) fn classify_report(&self, report: &Report) -> ReportFate {
        if report.run != self.run {
            return ReportFate::OtherRun;
        }
        let Some(tok) = self.tokens.get(&report.token) else {
            return match self.finished.get(&report.token) {
                Some((epoch, seq, agent)) if report.epoch == *epoch && report.agent == *agent => {
                    ReportFate::FinishedAgain(AckEntry { token: report.token, epoch: *epoch, seq: *seq, done: true })
                }
                _ => ReportFate::UnknownToken,
            };
        };
        if report.epoch != tok.epoch {
            return match report.epoch < tok.epoch {
                true => ReportFate::Stale { first: !tok.stale_traced.contains(&report.epoch) },
                false => ReportFate::FutureEpoch,
            };
        }
        if tok.agent.as_deref() != Some(report.agent.as_str()) {
            return ReportFate::NotHolder;
        }
        if self.agents.get(&report.agent).map(|a| a.incarnation) != Some(report.incarnation) {
            return ReportFate::OtherProcess;
        }
        if report.seq < tok.next_seq {
            return ReportFate::Old;
        }
        if report.seq > tok.next_seq {
            let room = tok.ahead.len() < REPORTS_AHEAD_MAX
                && tok.ahead_bytes + report.weight() <= REPORTS_AHEAD_BYTES_MAX
                && !tok.ahead.contains_key(&report.seq);
            return ReportFate::Ahead { room };
        }
        ReportFate::Next
    }

    /// Whether a report changes what the coordinator knows (it applies, waits ahead of a gap, or is the first
    /// stale one of its epoch, which the trace shows): only those are journaled. The others are answered, counted
    /// and dropped, and change nothing a replay needs — so a peer's garbage costs no disk.
    pub(super) fn admit_report(&self, report: &Report) -> bool {
        match self.classify_report(report) {
            ReportFate::Next | ReportFate::Ahead { room: true } | ReportFate::Stale { first: true } => true,
            // The first word from an agent that could not be told of the abort: it is told now (`tell_of_end`).
            ReportFate::UnknownToken => self.untold.contains_key(&report.agent),
            _ => false,
        }
    }

    /// A report from an agent, decoded. Reports of a token apply once each, in sequence order.
    pub(super) fn handle_report(&mut self, now_ms: u64, report: Report) {
        self.advance(now_ms);
        match self.classify_report(&report) {
            ReportFate::OtherRun => self.drop_msg(format!("report from `{}` for another run dropped", report.agent)),
            ReportFate::FinishedAgain(entry) => {
                // A duplicate of a finished token's report: acknowledge again, apply nothing.
                self.stats.dropped += 1;
                self.ack(report.agent, entry);
            }
            ReportFate::UnknownToken => {
                if self.untold.contains_key(&report.agent) {
                    self.tell_of_end(&report.agent);
                } else if self.is_ended_by_operator() {
                    // An agent still working for the run after its end (it missed the word): told again.
                    self.send(report.agent.clone(), ToAgent::Abort { run: self.run });
                }
                self.drop_msg(format!("report from `{}` for unknown token {} dropped", report.agent, report.token))
            }
            ReportFate::Stale { first } => self.stale_report(report, first),
            ReportFate::FutureEpoch => self.drop_msg(format!(
                "report from `{}` for token {} dropped: epoch {} was never dispatched",
                report.agent, report.token, report.epoch
            )),
            ReportFate::NotHolder => self.drop_msg(format!(
                "report for token {} dropped: it came from `{}`, which does not hold it",
                report.token, report.agent
            )),
            ReportFate::OtherProcess => self.drop_msg(format!(
                "report for token {} dropped: it came from another process than `{}`'s current one",
                report.token, report.agent
            )),
            ReportFate::Old => {
                let Some(tok) = self.tokens.get(&report.token) else { return };
                let entry = AckEntry { token: report.token, epoch: tok.epoch, seq: tok.next_seq - 1, done: false };
                self.stats.dropped += 1;
                self.ack(report.agent, entry);
            }
            ReportFate::Ahead { room: false } => self.stats.dropped += 1,
            ReportFate::Ahead { room: true } => {
                let Some(tok) = self.tokens.get_mut(&report.token) else { return };
                tok.ahead_bytes += report.weight();
                tok.ahead.insert(report.seq, report);
            }
            ReportFate::Next => self.next_report(report),
        }
    }

    /// A report of an older epoch (its segment was taken back): the agent is told to drop it, and the trace
    /// says so once per epoch.
    pub(super) fn stale_report(&mut self, report: Report, first: bool) {
        let Some(tok) = self.tokens.get_mut(&report.token) else { return };
        let epoch = tok.epoch;
        if first {
            if tok.stale_traced.len() >= STALE_EPOCHS_TRACED {
                tok.stale_traced.remove(0);
            }
            tok.stale_traced.push(report.epoch);
            let entry = self.program.steps[tok.entry.index()].name.clone();
            let mut rec = TraceRecord::new(self.now_ms, TraceEvent::RejectStale, &entry);
            rec.agent = Some(report.agent.clone());
            rec.token = Some(report.token.to_string());
            rec.epoch = Some(report.epoch);
            self.trace(rec);
        }
        let msg = ToAgent::Drop { run: self.run, token: report.token, epoch: report.epoch };
        let (agent, incarnation) = (report.agent.clone(), report.incarnation);
        self.outbox.push_back(CoordOutput::Send { agent, incarnation, msg });
        self.drop_msg(format!(
            "report from `{}` for token {} rejected: epoch {} is stale (current {epoch}); told to drop it",
            report.agent, report.token, report.epoch
        ));
    }

    /// The report the token waited for: it applies, and so do those held ahead that follow it.
    pub(super) fn next_report(&mut self, report: Report) {
        let Some(tok) = self.tokens.get_mut(&report.token) else { return };
        // A report on the token is as good as the agent saying it holds it.
        tok.confirmed = true;
        let id = report.token;
        let mut next = Some(report);
        while let Some(r) = next {
            let done = r.done;
            self.apply_report(r);
            if done {
                break;
            }
            next = self.tokens.get_mut(&id).and_then(|t| {
                let seq = t.next_seq;
                let r = t.ahead.remove(&seq)?;
                t.ahead_bytes = t.ahead_bytes.saturating_sub(r.weight());
                Some(r)
            });
        }
        self.settle();
    }

    pub(super) fn apply_report(&mut self, r: Report) {
        let Some(tok) = self.tokens.get(&r.token) else { return };
        let (segment, dispatched_ms, epoch) = (tok.segment, tok.dispatched_ms, tok.epoch);
        let placement = self.layout.segments[segment.index()].placement.clone();
        let program = Arc::clone(&self.program);
        self.apply_agent_vars(&r.agent, r.incarnation, r.vars_seq, &r.vars);
        // Never before the coordinator's last grid point: a report that comes late (lost and sent again, an agent
        // cut off for a while) cannot make the coordinator's own steps active in cycles that have passed without
        // them, or their actions would run fewer cycles than their step times say.
        let mut floor = self.engine.now_ms().max(self.now_ms - self.now_ms % self.cycle_ms);
        for ev in &r.events {
            // Agent times are offsets from the token's arrival; they are mapped onto this clock, never before
            // what the coordinator already recorded and never after now.
            let t_ms = dispatched_ms.saturating_add(ev.dt_ms).clamp(floor, self.now_ms.max(floor));
            floor = t_ms;
            self.apply_event(&r, &ev.kind, t_ms, (segment, epoch), &placement, &program);
        }
        let agent = r.agent.clone();
        self.ack(agent.clone(), AckEntry { token: r.token, epoch, seq: r.seq, done: r.done });
        if let Some(tok) = self.tokens.get_mut(&r.token) {
            tok.next_seq = r.seq + 1;
            // Heard from: its agent is asked only if it goes quiet from now on.
            tok.resend_at_ms = self.now_ms + ASK_FIRST_MS;
            tok.resend_backoff_ms = ASK_FIRST_MS;
        }
        if r.done {
            self.finish(r.token, epoch, r.seq, agent);
        }
    }

    /// One event of report `r`, at `t_ms` on this clock, of the token's `segment` in `epoch` (whose steps run at
    /// `placement`): mirrored in the engine, traced, or refused as not the agent's to report.
    fn apply_event(
        &mut self,
        r: &Report,
        kind: &AgentEventKind,
        t_ms: u64,
        (segment, epoch): (SegmentId, u32),
        placement: &Placement,
        program: &Program,
    ) {
        // Which run of its segment it happened in: a test can tell a segment run twice in one epoch.
        let rec = |event: TraceEvent, name: &str, message: Option<String>| {
            let mut rec = TraceRecord::new(t_ms, event, name);
            rec.agent = Some(r.agent.clone());
            rec.token = Some(r.token.to_string());
            rec.epoch = Some(epoch);
            rec.message = message;
            rec
        };
        match kind {
            AgentEventKind::Fire { transition } => {
                let t = TransitionId(*transition);
                let ok = (*transition as usize) < program.transitions.len()
                    && self.layout.agent_judges(program, t) == Some(segment);
                if !ok {
                    self.drop_msg(format!("`{}` reported transition {transition}, which is not its to clear", r.agent));
                    return;
                }
                if let Err(e) = self.engine.handle_remote(t_ms, RemoteInput::Fire(t)) {
                    self.drop_msg(format!("`{}` reported a clearing this coordinator cannot mirror: {e}", r.agent));
                    return;
                }
                self.drain_engine();
            }
            AgentEventKind::ActionOn { action } | AgentEventKind::ActionOff { action } => {
                let Some(info) = program.actions.get(*action as usize) else {
                    self.drop_msg(format!("`{}` reported unknown action {action}", r.agent));
                    return;
                };
                if self.layout.action_placement[*action as usize] != *placement {
                    self.drop_msg(format!("`{}` reported action `{}`, which does not run there", r.agent, info.name));
                    return;
                }
                let on = matches!(kind, AgentEventKind::ActionOn { .. });
                let rec = rec(if on { TraceEvent::ActionOn } else { TraceEvent::ActionOff }, &info.name, None);
                self.trace(rec);
            }
            AgentEventKind::SkillDone { action } => {
                let Some(info) = program.actions.get(*action as usize) else { return };
                let rec = rec(TraceEvent::SkillDone, &info.name, None);
                self.trace(rec);
            }
            AgentEventKind::SkillFault { action, message } => {
                let Some(info) = program.actions.get(*action as usize) else { return };
                let rec = rec(TraceEvent::SkillFault, &info.name, Some(message.clone()));
                self.trace(rec);
                let text = format!("skill of action `{}` on `{}` failed: {message}", info.name, r.agent);
                // A fault the chart reads (the association's second indicator) is the chart's to handle, as
                // the cell's rework loop does; one it cannot see needs a person.
                if self.chart_reads_fault(*action) {
                    self.log(Level::Warn, text);
                } else {
                    self.event_alarm(t_ms, &r.agent, text);
                }
            }
            AgentEventKind::Overrun { step, .. } | AgentEventKind::OverrunAcknowledged { step } => {
                let s = StepId(*step);
                if !self.layout.segments[segment.index()].steps.contains(&s) {
                    self.drop_msg(format!("`{}` reported step {step}, which is not of its segment", r.agent));
                    return;
                }
                if let AgentEventKind::Overrun { why, .. } = kind {
                    let why: String = why.chars().take(crate::limits::ALARM_TEXT_CHARS_MAX).collect();
                    self.on_overrun(t_ms, s, Some((r.token, epoch)), Some(&r.agent), &why);
                } else {
                    self.overrun_acknowledged(r.token, s);
                }
            }
            AgentEventKind::Gated { seq } => self.gated(r.token, *seq),
            AgentEventKind::Waiting { transition, waiting } => {
                let t = TransitionId(*transition);
                if self.layout.agent_judges(program, t) != Some(segment) {
                    self.drop_msg(format!("`{}` reported transition {transition}, which is not its", r.agent));
                    return;
                }
                if *waiting {
                    self.agent_waiting.insert(t);
                } else {
                    self.agent_waiting.remove(&t);
                }
            }
            AgentEventKind::Held | AgentEventKind::Released => {
                let held = matches!(kind, AgentEventKind::Held);
                self.hold_confirmed(r.token, held);
            }
            AgentEventKind::Fault { message } => {
                let rec = rec(TraceEvent::Fault, &program.name, Some(message.clone()));
                self.trace(rec);
                self.event_alarm(t_ms, &r.agent, format!("run-time fault on `{}`: {message}", r.agent));
            }
        }
    }

    /// Whether the chart reads the faults of `action`'s skill: an association of it has a fault indicator.
    fn chart_reads_fault(&self, action: u32) -> bool {
        (0..self.program.steps.len() as u32).map(StepId).any(|s| {
            self.program
                .associations(s)
                .iter()
                .zip(self.program.indicators(s))
                .any(|(a, inds)| a.action.0 == action && inds.len() >= 2)
        })
    }
}
