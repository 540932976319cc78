//! Tokens: made when the engine enters a placed segment, dispatched to an agent (or left waiting), sent again,
//! acknowledged, finished when they come back, and restarted on another agent.

use std::collections::BTreeMap;
use std::sync::Arc;

use crate::cluster::layout::{Placement, SegmentId};
use crate::cluster::runtime::{Level, COORDINATOR};
use crate::cluster::wire::{AckEntry, ToAgent, TokenId, VarValue};
use crate::exec::engine::{Event, EventKind, RemoteInput};
use crate::exec::program::{StepId, VarId};
use crate::exec::trace::{self, Output, TraceEvent, TraceRecord};
use crate::limits::{ACK_DELAY_MS, FINISHED_TOKENS_REMEMBERED};

use super::state::{AgentState, TokenState};
use super::{CoordOutput, Coordinator, LossPolicy, DISPATCH_RESEND_FIRST_MS};

impl Coordinator {
    /// The agent that holds the token of a placed step's segment, if it is out.
    pub(super) fn holder(&self, s: StepId) -> Option<&str> {
        self.segment_holder(self.layout.segment_of[s.index()]?)
    }

    /// Where token `id` is, for an operator's words: "`Weld2`" — its segment's active steps now, as its agent
    /// reported them — with "(entered at `Weld`)" when it was dispatched at another step.
    pub(super) fn token_at(&self, id: TokenId) -> String {
        let Some(tok) = self.tokens.get(&id) else { return String::new() };
        let entry = &self.program.steps[tok.entry.index()].name;
        let now: Vec<String> = self.segment_at(tok.segment).map(|s| format!("`{s}`")).collect();
        match now.as_slice() {
            [] => format!("`{entry}`"),
            [one] if *one == format!("`{entry}`") => one.clone(),
            _ => format!("{} (entered at `{entry}`)", now.join(", ")),
        }
    }

    /// The names of segment `g`'s active steps, as the coordinator mirrors them: where its token is now.
    pub(super) fn segment_at(&self, g: SegmentId) -> impl Iterator<Item = &str> + '_ {
        self.engine
            .active_steps()
            .iter()
            .filter(move |s| self.layout.segment_of[s.index()] == Some(g))
            .map(|s| self.program.steps[s.index()].name.as_str())
    }

    pub(super) fn segment_holder(&self, g: SegmentId) -> Option<&str> {
        self.tokens.get(&self.by_segment[g.index()]?)?.agent.as_deref()
    }

    pub(super) fn drain_engine(&mut self) {
        while let Some(ev) = self.engine.poll_event() {
            self.on_engine_event(ev);
        }
    }

    pub(super) fn on_engine_event(&mut self, ev: Event) {
        let program = Arc::clone(&self.program);
        match ev.kind {
            EventKind::Overrun(s) => {
                let why = self.engine.take_overrun_why(s).unwrap_or_else(|| self.engine.why(s)).summary();
                return self.on_overrun(ev.t_ms, s, None, None, &why);
            }
            EventKind::Deactivate(s) if !self.supervised.is_empty() => self.supervised_step_left(s),
            _ => {}
        }
        let mut created = None;
        if let EventKind::Activate(s) = ev.kind {
            if let Some(g) = self.layout.segment_of[s.index()] {
                if self.by_segment[g.index()].is_none() {
                    created = Some(self.new_token(g, s));
                }
            }
        }
        let by = match ev.kind {
            EventKind::Activate(s) | EventKind::Deactivate(s) => self.holder(s),
            EventKind::Fire(t) => self.layout.agent_judges(&program, t).and_then(|g| self.segment_holder(g)),
            _ => None,
        };
        let agent = by.map(str::to_string);
        let mut fault = None;
        let mut rec = match trace::of_event(&program, ev) {
            Output::Trace(rec) => rec,
            Output::Fault { t_ms, message } => {
                let mut rec = TraceRecord::new(t_ms, TraceEvent::Fault, &program.name);
                rec.message = Some(message.clone());
                fault = Some((t_ms, message));
                rec
            }
        };
        rec.agent = agent;
        self.trace(rec);
        if let Some((t_ms, message)) = fault {
            self.event_alarm(t_ms, COORDINATOR, format!("run-time fault on the coordinator: {message}"));
        }
        if let Some(id) = created {
            self.emit_dispatch_or_wait(id);
        }
    }

    pub(super) fn new_token(&mut self, g: SegmentId, entry: StepId) -> TokenId {
        let id = self.new_token.next_id();
        let tok = TokenState {
            segment: g,
            entry,
            epoch: 1,
            agent: None,
            next_seq: 0,
            ahead: BTreeMap::new(),
            ahead_bytes: 0,
            stale_traced: Vec::new(),
            dispatched_ms: self.now_ms,
            paused: false,
            confirmed: true,
            resend_at_ms: 0,
            resend_backoff_ms: 0,
            incarnation: uuid::Uuid::nil(),
            reassign_at_ms: None,
            hold: false,
            hold_ok: true,
            hold_resend_at_ms: 0,
            hold_backoff_ms: 0,
            gate: Default::default(),
        };
        let hold = self.token_should_hold(&tok);
        self.tokens.insert(id, tok);
        self.by_segment[g.index()] = Some(id);
        if hold {
            if let Some(t) = self.tokens.get_mut(&id) {
                t.hold = true;
            }
            for s in self.layout.segments[g.index()].steps.clone() {
                self.engine.set_held(self.now_ms, s, true);
            }
        }
        if let Some(agent) = self.choose_agent(g) {
            self.assign(id, agent);
        }
        id
    }

    /// A live agent of the segment's placement that has the skills its steps run: by name, or the least busy of
    /// the role (round robin among equals).
    pub(super) fn choose_agent(&mut self, segment: SegmentId) -> Option<String> {
        let g = segment.index();
        match &self.layout.segments[g].placement {
            Placement::Coordinator => None,
            Placement::Agent(name) => self
                .agents
                .get(name)
                .filter(|a| a.alive && !a.conflict)
                .filter(|_| self.has_skills_for(name, g))
                .map(|_| name.clone()),
            Placement::Role(role) => {
                let able: Vec<(&String, usize)> = self
                    .agents
                    .iter()
                    .filter(|(_, a)| a.alive && !a.conflict && a.roles.iter().any(|r| r == role))
                    .filter(|(n, _)| self.has_skills_for(n, g))
                    .map(|(n, a)| (n, a.tokens))
                    .collect();
                let least = able.iter().map(|(_, n)| *n).min()?;
                let tied: Vec<&String> = able.iter().filter(|(_, n)| *n == least).map(|(name, _)| *name).collect();
                let pick = tied[self.round_robin % tied.len()].clone();
                self.round_robin = self.round_robin.wrapping_add(1);
                Some(pick)
            }
        }
    }

    pub(super) fn assign(&mut self, id: TokenId, agent: String) {
        let incarnation = self.agents.get_mut(&agent).map(|a| {
            a.tokens += 1;
            a.incarnation
        });
        if let Some(tok) = self.tokens.get_mut(&id) {
            tok.agent = Some(agent);
            tok.incarnation = incarnation.unwrap_or_default();
        }
    }

    /// Sends a token to its agent, or says why it waits.
    pub(super) fn emit_dispatch_or_wait(&mut self, id: TokenId) {
        self.send_token(id, TraceEvent::Dispatch);
    }

    /// Sends a token to its agent, traced as `event` (`dispatch`, or `resume` when a paused token goes back to
    /// its agent in the same epoch), or says why it waits.
    pub(super) fn send_token(&mut self, id: TokenId, event: TraceEvent) {
        let Some(tok) = self.tokens.get(&id) else { return };
        let entry_name = self.program.steps[tok.entry.index()].name.clone();
        let placement = self.layout.segments[tok.segment.index()].placement.clone();
        let (epoch, segment) = (tok.epoch, tok.segment);
        if tok.agent.is_none() {
            if !self.waiting.contains(&id) {
                self.waiting.push(id);
                let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Wait, &entry_name);
                rec.token = Some(id.to_string());
                rec.epoch = Some(epoch);
                self.trace(rec);
                let live = |a: &AgentState| a.alive && !a.conflict;
                let why = match &placement {
                    Placement::Agent(a) if self.agents.get(a).is_some_and(live) => {
                        format!("agent `{a}` lacks {}", self.skills_lacked(a, segment.index()))
                    }
                    Placement::Agent(a) => format!("no live agent named `{a}`"),
                    Placement::Role(r) if self.agents.values().any(|a| live(a) && a.roles.contains(r)) => {
                        format!("no live agent with role `{r}` has the skills its steps run")
                    }
                    Placement::Role(r) => format!("no live agent with role `{r}`"),
                    Placement::Coordinator => "it is placed on the coordinator".to_string(),
                };
                self.log(Level::Warn, format!("token for step `{entry_name}` waits: {why}"));
            }
            return;
        }
        // What changed since the last update is published first, so that the dispatch's values carry an update
        // number of their own: an agent takes a value only from an update newer than the last it applied, and
        // would otherwise keep what it had for a variable that changed since (a P action then reads it stale).
        self.publish_vars();
        let Some((agent, msg)) = self.dispatch_msg(id) else { return };
        if let Some(tok) = self.tokens.get_mut(&id) {
            tok.dispatched_ms = self.now_ms;
            tok.resend_at_ms = self.now_ms + DISPATCH_RESEND_FIRST_MS;
            tok.resend_backoff_ms = DISPATCH_RESEND_FIRST_MS;
            // A held token arrives held: its agent confirms that in its first report.
            if tok.hold {
                tok.hold_ok = false;
                tok.hold_resend_at_ms = self.now_ms + DISPATCH_RESEND_FIRST_MS;
                tok.hold_backoff_ms = DISPATCH_RESEND_FIRST_MS;
            }
        }
        if event == TraceEvent::Dispatch {
            self.stats.dispatched += 1;
        }
        let mut rec = TraceRecord::new(self.now_ms, event, &entry_name);
        rec.agent = Some(agent.clone());
        rec.token = Some(id.to_string());
        rec.epoch = Some(epoch);
        self.trace(rec);
        self.send(agent, msg);
    }

    /// The dispatch of a token to its agent, as it stands now (callers publish the variables first, so that
    /// `vars_seq` numbers these values).
    pub(super) fn dispatch_msg(&self, id: TokenId) -> Option<(String, ToAgent)> {
        let tok = self.tokens.get(&id)?;
        let agent = tok.agent.clone()?;
        let vars = self.values_for(&agent);
        let msg = ToAgent::Dispatch {
            run: self.run,
            chart: self.hash.clone(),
            token: id,
            epoch: tok.epoch,
            segment: tok.segment.0,
            entry: tok.entry.0,
            vars,
            vars_seq: self.vars_seq,
            acks: Vec::new(),
            fence: self.policy == LossPolicy::Reassign,
            peers: self.peers.clone(),
            held: tok.hold,
            mode: self.engine.mode(),
        };
        Some((agent, msg))
    }

    /// What a dispatch or a join gives `agent`: the value of every variable code on agents reads, and of every
    /// variable `agent` writes. A process that has not taken part in the run yet (a restarted one) starts from
    /// these even for its own, or it would compute on the chart's initial values.
    pub(super) fn values_for(&self, agent: &str) -> Vec<VarValue> {
        (0..self.program.vars.len())
            .filter(|&i| self.layout.read_by_agents[i] || self.serves(agent, &self.layout.writer[i]))
            .map(|i| VarValue::new(VarId(i as u32), self.engine.value(VarId(i as u32))))
            .collect()
    }

    /// A join for `agent`'s current process: the run's values and writers, before any token.
    pub(super) fn join_msg(&self, agent: &str) -> ToAgent {
        ToAgent::Join {
            run: self.run,
            chart: self.hash.clone(),
            vars: self.values_for(agent),
            vars_seq: self.vars_seq,
            peers: self.peers.clone(),
        }
    }

    pub(super) fn finish(&mut self, id: TokenId, epoch: u32, seq: u32, agent: String) {
        let Some(tok) = self.tokens.remove(&id) else { return };
        self.by_segment[tok.segment.index()] = None;
        if let Some(a) = self.agents.get_mut(&agent) {
            a.tokens = a.tokens.saturating_sub(1);
        }
        self.forget_if_gone(&agent);
        let still =
            self.layout.segments[tok.segment.index()].steps.iter().find(|&&s| self.engine.is_active(s)).copied();
        if let Some(s) = still {
            let name = self.program.steps[s.index()].name.clone();
            self.log(
                Level::Error,
                format!("token {id} came back from `{agent}` while its step `{name}` is still active"),
            );
        }
        self.stats.returned += 1;
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Return, &self.program.steps[tok.entry.index()].name);
        rec.agent = Some(agent.clone());
        rec.token = Some(id.to_string());
        rec.epoch = Some(epoch);
        self.trace(rec);
        if self.finished_order.len() >= FINISHED_TOKENS_REMEMBERED {
            if let Some(old) = self.finished_order.pop_front() {
                self.finished.remove(&old);
            }
        }
        self.finished.insert(id, (epoch, seq, agent));
        self.finished_order.push_back(id);
    }

    /// Takes a token back from its agent: a new epoch, the segment's steps back to its first step in the mirror,
    /// and a dispatch to a live agent of the placement (or a wait for one).
    pub(super) fn reassign(&mut self, id: TokenId) {
        self.restart_on(id, None);
    }

    /// A new epoch from the segment's first step, on `agent` or on whichever live agent the placement picks.
    pub(super) fn restart_on(&mut self, id: TokenId, agent: Option<String>) {
        let Some(tok) = self.tokens.get_mut(&id) else { return };
        tok.epoch += 1;
        tok.next_seq = 0;
        tok.ahead.clear();
        tok.ahead_bytes = 0;
        tok.paused = false;
        tok.reassign_at_ms = None;
        tok.confirmed = true;
        let (segment, entry, old) = (tok.segment, tok.entry, tok.agent.take());
        if let Some(a) = old.and_then(|a| self.agents.get_mut(&a)) {
            a.tokens = a.tokens.saturating_sub(1);
        }
        let now = self.now_ms;
        for s in self.layout.segments[segment.index()].steps.clone() {
            if self.engine.is_active(s) && s != entry {
                let _ = self.engine.handle_remote(now, RemoteInput::Deactivate(s));
            }
        }
        if !self.engine.is_active(entry) {
            let _ = self.engine.handle_remote(now, RemoteInput::Activate(entry));
        }
        self.drain_engine();
        // The agent it came back on, if that process has what the segment runs; else whichever the placement picks.
        let agent = agent.filter(|a| self.has_skills_for(a, segment.index()));
        if let Some(agent) = agent.or_else(|| self.choose_agent(segment)) {
            self.assign(id, agent);
        }
        self.emit_dispatch_or_wait(id);
    }

    /// Acknowledgements ride on the dispatches about to leave to the same agent; in a cycle (`due`), the rest
    /// leave together once they are `ACK_DELAY_MS` old, or at once when the run is over.
    pub(super) fn flush_acks(&mut self, due: bool) {
        if self.acks.is_empty() {
            return;
        }
        for out in self.outbox.iter_mut() {
            if let CoordOutput::Send { agent, msg: ToAgent::Dispatch { acks, .. }, .. } = out {
                if let Some(owed) = self.acks.remove(agent.as_str()) {
                    acks.extend(owed);
                }
            }
        }
        if self.acks.is_empty() {
            return;
        }
        if (due && self.now_ms >= self.acks_since_ms + ACK_DELAY_MS) || self.is_terminal() {
            for (agent, acks) in std::mem::take(&mut self.acks) {
                self.send(agent, ToAgent::Ack { run: self.run, acks });
            }
        }
    }

    /// A command for `agent`'s current process; none for an agent this coordinator does not know. A dispatch or
    /// a join makes the process one that takes part in the run.
    pub(super) fn send(&mut self, agent: String, msg: ToAgent) {
        if let Some(a) = self.agents.get_mut(&agent) {
            a.joined |= matches!(msg, ToAgent::Dispatch { .. } | ToAgent::Join { .. });
            let incarnation = a.incarnation;
            self.outbox.push_back(CoordOutput::Send { agent, incarnation, msg });
        }
    }

    pub(super) fn ack(&mut self, agent: String, entry: AckEntry) {
        if self.acks.is_empty() {
            self.acks_since_ms = self.now_ms;
        }
        self.acks.entry(agent).or_default().push(entry);
    }
}
