//! Operators' commands (`baton ctl`): the run's PackML state moved by the standard's table, tokens held and released
//! on their agents and the run's state following their confirmations, a stop, an abort, and alarms acknowledged and
//! shelved. Every command, accepted or refused, is a trace record with who sent it and why.
//!
//! A whole-run `hold` (or `suspend`, or `stop`) holds every token: the coordinator's own steps are held in its
//! engine, and each agent holding a token is told to hold it (`ToAgent::Hold`, sent again until confirmed). The run
//! is `held` only when every token out on an agent is confirmed held — nothing of it runs there any more. `hold
//! --agent A` and `hold --step S` hold only the tokens on A, or the token whose segment holds S, while the run
//! stays in Execute. An `abort` ends the run at once: every agent is told, every token is abandoned (with an alarm
//! for each one whose agent cannot be reached), and the actions get their final scan.

use std::collections::BTreeSet;

use crate::cluster::layout::Placement;
use crate::cluster::runtime::alarms::{AlarmChange, AlarmId, AlarmRefusal};
use crate::cluster::runtime::packml::{Command, State};
use crate::cluster::runtime::Level;
use crate::cluster::wire::{CtlRequest, ToAgent, TokenId};
use crate::exec::program::StepId;
use crate::exec::trace::{TraceEvent, TraceRecord};

use super::state::TokenState;
use super::{CoordOutput, Coordinator};

/// First and largest delay before a hold or release that no confirmation answered is sent again.
const HOLD_RESEND_FIRST_MS: u64 = 200;

const HOLD_RESEND_MAX_MS: u64 = 2_000;

impl Coordinator {
    /// An operator's command. Accepted or refused, it is traced (`command` or `command_refused`, with `by` and the
    /// reason); the answer says what happened, or why not and what is legal now.
    pub fn handle_command(&mut self, now_ms: u64, req: &CtlRequest) -> Result<String, String> {
        self.advance(now_ms);
        // The command's record comes before what it caused.
        let mark = self.outbox.len();
        let result = self.command(req);
        let (event, message) = match &result {
            Ok(_) => (TraceEvent::Command, req.reason.clone()),
            Err(why) => (TraceEvent::CommandRefused, why.clone()),
        };
        let mut rec = TraceRecord::new(self.now_ms, event, &req.command.to_ascii_lowercase());
        rec.message = (!message.is_empty()).then_some(message);
        rec.by = Some(req.by.clone());
        rec.agent = req.agent.clone();
        self.outbox.insert(mark, CoordOutput::Trace(rec));
        match &result {
            Ok(m) => self.log(Level::Info, format!("{} by {}: {m}", req.command, req.by)),
            Err(why) => self.log(Level::Warn, format!("{} by {} refused: {why}", req.command, req.by)),
        }
        self.after_command();
        // A PackML command's answer is the state the run is in now: one that left by itself meanwhile (nothing to
        // wait for) is the one to tell. Other commands say what they did (`mode step`: the mode).
        let whole_run = req.agent.is_none() && req.step.is_none();
        if whole_run && Command::from_name(&req.command.to_ascii_lowercase()).is_some() {
            return result.map(|_| format!("the run is {}", self.run_state.name()));
        }
        result
    }

    fn command(&mut self, req: &CtlRequest) -> Result<String, String> {
        let name = req.command.to_ascii_lowercase();
        let target = req.target.as_deref();
        match name.as_str() {
            "ack" => return self.ack_command(req),
            "shelve" => return self.shelve_command(req),
            "unshelve" => return self.unshelve_command(req),
            "mode" => return self.mode_command(target),
            "confirm" => return self.confirm_command(target),
            "force" => return self.force_command(target),
            "activate" => return self.switch_command(true, target),
            "deactivate" => return self.switch_command(false, target),
            "move" => return self.move_command(target, req.to.as_deref()),
            _ => {}
        }
        let Some(command) = Command::from_name(&name) else {
            return Err(format!(
                "unknown command `{}`: hold, unhold, suspend, unsuspend, stop, abort, reset, start, clear, mode, \
                 confirm, force, activate, deactivate, move, ack, shelve, unshelve",
                req.command
            ));
        };
        if req.agent.is_some() || req.step.is_some() {
            return self.partial_hold(command, req);
        }
        if matches!(command, Command::Reset | Command::Clear) && !self.stays {
            // The table allows them only in states a run ends in: without `--stay`, `baton run` ends there.
            return Err(format!(
                "`{}` needs a run that stays at its end: this one ends when it is complete, stopped or aborted \
                 (start it with `baton run --stay` to clear and reset it)",
                command.name()
            ));
        }
        let to = self.run_state.apply(command).map_err(|r| r.to_string())?;
        self.change_state(to);
        if command == Command::Clear {
            // Nothing is left to clear: the abort ended every segment (agents that could not be told are told when
            // they are heard from again).
            if let Some(next) = to.when_done() {
                self.change_state(next);
            }
        }
        if command == Command::Start {
            // Starting has nothing to wait for: the first cycle runs at the next grid time.
            if let Some(next) = to.when_done() {
                self.change_state(next);
            }
        }
        if command == Command::Abort {
            self.abort_now();
        }
        Ok(format!("the run is {}", self.run_state.name()))
    }

    /// `hold --agent A` / `--step S` and their `unhold`: only those parts.
    fn partial_hold(&mut self, command: Command, req: &CtlRequest) -> Result<String, String> {
        if !matches!(command, Command::Hold | Command::Unhold) {
            return Err(format!(
                "`{}` applies to the whole run: --agent and --step go with hold and unhold",
                command.name()
            ));
        }
        if !self.run_state.is_inside(crate::cluster::runtime::packml::Machine::Running)
            || matches!(self.run_state, State::Complete | State::Completing)
        {
            return Err(format!("cannot {} part of a run that is {}", command.name(), self.run_state.name()));
        }
        let hold = command == Command::Hold;
        let mut said = Vec::new();
        if let Some(agent) = &req.agent {
            if !crate::cluster::keys::is_valid_name(agent) {
                return Err(format!("`{agent}` is not an agent name"));
            }
            if hold && !self.partial.agents.contains(agent) {
                self.known_agent(agent)?;
                if self.partial.agents.len() >= HELD_AGENTS_MAX {
                    return Err(format!("{HELD_AGENTS_MAX} agents are held already: hold the whole run instead"));
                }
            }
            let changed =
                if hold { self.partial.agents.insert(agent.clone()) } else { self.partial.agents.remove(agent) };
            if !changed {
                return Err(format!("agent `{agent}` is {}held", if hold { "already " } else { "not " }));
            }
            said.push(format!("agent `{agent}`"));
        }
        if let Some(step) = &req.step {
            let s = self.program.step_by_name(step).ok_or_else(|| {
                let names = self.program.steps.iter().map(|s| s.name.as_str());
                let hint = crate::front::pragma::did_you_mean(step, names);
                format!("chart `{}` has no step `{step}`{hint}", self.program.name)
            })?;
            let changed = if hold { self.partial.steps.insert(s) } else { self.partial.steps.remove(&s) };
            if !changed {
                return Err(format!("step `{step}` is {}held", if hold { "already " } else { "not " }));
            }
            said.push(format!("the branch of step `{}`", self.program.steps[s.index()].name));
        }
        Ok(format!("{} {}", if hold { "holding" } else { "releasing" }, said.join(" and ")))
    }

    fn ack_command(&mut self, req: &CtlRequest) -> Result<String, String> {
        let comment = (!req.reason.is_empty()).then_some(req.reason.as_str());
        let target = req.target.as_deref().unwrap_or("");
        let changes = if target.eq_ignore_ascii_case("all") {
            self.alarms.acknowledge_all(self.now_ms, &req.by, comment)
        } else {
            let id = parse_alarm(target)?;
            self.alarms.acknowledge(self.now_ms, id, &req.by, comment).map_err(|e| e.to_string())?
        };
        let n = changes.iter().filter(|c| matches!(c, AlarmChange::Acknowledged { .. })).count();
        self.alarm_changes(changes);
        Ok(format!("{n} alarm(s) acknowledged"))
    }

    fn shelve_command(&mut self, req: &CtlRequest) -> Result<String, String> {
        let id = parse_alarm(req.target.as_deref().unwrap_or(""))?;
        let for_ms = req.for_ms.ok_or("shelve needs --for DURATION")?;
        let reason = (!req.reason.is_empty()).then_some(req.reason.as_str());
        let change =
            self.alarms.shelve(self.now_ms, id, &req.by, for_ms, reason).map_err(|e: AlarmRefusal| e.to_string())?;
        self.alarm_changes(vec![change]);
        Ok(format!("alarm {id} shelved for {for_ms} ms: out of the active list until then, or until `unshelve {id}`"))
    }

    fn unshelve_command(&mut self, req: &CtlRequest) -> Result<String, String> {
        let id = parse_alarm(req.target.as_deref().unwrap_or(""))?;
        let change = self.alarms.unshelve(id, &req.by).map_err(|e: AlarmRefusal| e.to_string())?;
        self.alarm_changes(vec![change]);
        Ok(format!("alarm {id} unshelved: back in the active list"))
    }

    /// Shelves whose time ran out go back to the active list, traced.
    pub(super) fn expire_shelves(&mut self) {
        let changes = self.alarms.expire_shelves(self.now_ms);
        self.alarm_changes(changes);
    }

    /// Trace records of alarms' changes: `ack`, `shelve`, `alarm_clear` (back to normal).
    pub(super) fn alarm_changes(&mut self, changes: Vec<AlarmChange>) {
        for change in changes {
            if let AlarmChange::Acknowledged { id, .. } = &change {
                self.supervision_acknowledged(*id);
            }
            let rec = match change {
                AlarmChange::Acknowledged { id, source, by, comment } => {
                    let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Ack, &source);
                    rec.id = Some(id.0);
                    rec.by = Some(by);
                    rec.message = comment;
                    rec
                }
                AlarmChange::Shelved { id, source, shelf, until_ms } => {
                    let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Shelve, &source);
                    rec.id = Some(id.0);
                    rec.message = Some(match &shelf.reason {
                        Some(why) => format!("until {until_ms} ms: {why}"),
                        None => format!("until {until_ms} ms"),
                    });
                    rec.by = Some(shelf.by);
                    rec
                }
                AlarmChange::Unshelved { id, source, shelf, by } => {
                    let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Unshelve, &source);
                    rec.id = Some(id.0);
                    let why = shelf.reason.as_deref().map(|r| format!(" ({r})")).unwrap_or_default();
                    rec.message = Some(match &by {
                        Some(who) => format!("shelved by {}{why}, unshelved by {who}", shelf.by),
                        None => format!("shelved by {}{why}, its shelf time ran out", shelf.by),
                    });
                    // Who ended the shelf: the operator who unshelved it, or (its time ran out) who shelved it.
                    rec.by = Some(by.unwrap_or(shelf.by));
                    rec
                }
                AlarmChange::Normal { id, source } => {
                    let mut rec = TraceRecord::new(self.now_ms, TraceEvent::AlarmClear, &source);
                    rec.id = Some(id.0);
                    rec
                }
                AlarmChange::Raised { .. } | AlarmChange::CauseGone { .. } => continue,
            };
            self.trace(rec);
        }
    }

    /// What a command changed reaches the tokens, the engine and the run's state.
    pub(super) fn after_command(&mut self) {
        self.sync_holds();
        self.progress_state();
        self.settle();
    }

    /// Whether the whole run is held: every token, and the coordinator's own steps.
    fn whole_hold(&self) -> bool {
        matches!(
            self.run_state,
            State::Holding | State::Held | State::Suspending | State::Suspended | State::Stopping | State::Stopped
        )
    }

    /// Whether a token should be held now.
    pub(super) fn token_should_hold(&self, tok: &TokenState) -> bool {
        self.whole_hold()
            || tok.agent.as_ref().is_some_and(|a| self.partial.agents.contains(a))
            || self.layout.segments[tok.segment.index()].steps.iter().any(|s| self.partial.steps.contains(s))
    }

    /// Brings every token's hold and every step of the engine in line with the run's state and the partial
    /// holds; a token whose hold changed is told so.
    pub(super) fn sync_holds(&mut self) {
        let ids: Vec<TokenId> = self.tokens.keys().copied().collect();
        for id in ids {
            let want = self.token_should_hold(&self.tokens[&id]);
            let tok = self.tokens.get_mut(&id).expect("listed");
            if tok.hold == want {
                continue;
            }
            tok.hold = want;
            tok.hold_ok = tok.agent.is_none();
            tok.hold_resend_at_ms = self.now_ms + HOLD_RESEND_FIRST_MS;
            tok.hold_backoff_ms = HOLD_RESEND_FIRST_MS;
            self.send_hold(id);
        }
        let whole = self.whole_hold();
        for i in 0..self.program.steps.len() {
            let s = StepId(i as u32);
            let by_token = self.layout.segment_of[i]
                .and_then(|g| self.by_segment[g.index()])
                .and_then(|id| self.tokens.get(&id))
                .is_some_and(|t| t.hold);
            let want = whole || self.partial.steps.contains(&s) || by_token;
            if self.engine.is_held(s) != want {
                self.engine.set_held(self.now_ms, s, want);
            }
        }
    }

    fn send_hold(&mut self, id: TokenId) {
        let Some(tok) = self.tokens.get(&id) else { return };
        let Some(agent) = tok.agent.clone() else { return };
        let msg = ToAgent::Hold { run: self.run, token: id, epoch: tok.epoch, held: tok.hold };
        self.send(agent, msg);
    }

    /// Holds and releases that no confirmation answered go again, with doubling delays.
    pub(super) fn resend_holds(&mut self) {
        let now = self.now_ms;
        let due: Vec<TokenId> = self
            .tokens
            .iter()
            .filter(|(_, t)| !t.hold_ok && t.hold_resend_at_ms <= now && t.agent.is_some())
            .map(|(id, _)| *id)
            .collect();
        for id in due {
            if let Some(t) = self.tokens.get_mut(&id) {
                t.hold_backoff_ms = (t.hold_backoff_ms * 2).min(HOLD_RESEND_MAX_MS);
                t.hold_resend_at_ms = now + t.hold_backoff_ms;
            }
            self.send_hold(id);
        }
    }

    /// When a hold or release is next sent again.
    pub(super) fn next_hold_resend_ms(&self) -> Option<u64> {
        self.tokens.values().filter(|t| !t.hold_ok && t.agent.is_some()).map(|t| t.hold_resend_at_ms).min()
    }

    /// An agent confirmed that a token is held (`held`) or released.
    pub(super) fn hold_confirmed(&mut self, id: TokenId, held: bool) {
        if let Some(tok) = self.tokens.get_mut(&id) {
            if tok.hold == held {
                tok.hold_ok = true;
            }
        }
        self.progress_state();
    }

    /// An acting state leaves by itself when its work is done: Holding, Suspending and Stopping once every token
    /// out on an agent is confirmed held; Unholding and Unsuspending once every one is confirmed released.
    pub(super) fn progress_state(&mut self) {
        let done = match self.run_state {
            State::Holding | State::Suspending | State::Stopping => {
                self.tokens.values().all(|t| t.agent.is_none() || (t.hold && t.hold_ok))
            }
            State::Unholding | State::Unsuspending => {
                self.tokens.values().all(|t| t.agent.is_none() || (!t.hold && t.hold_ok))
            }
            _ => false,
        };
        if let (true, Some(next)) = (done, self.run_state.when_done()) {
            self.change_state(next);
            if next == State::Stopped {
                self.end_segments();
            } else {
                self.sync_holds();
            }
        }
    }

    /// The run is aborted: every agent taking part is told, every token abandoned (an alarm for each whose agent
    /// cannot be reached: it stops the segment itself when it hears of the abort, or when its fence says so), and
    /// the coordinator's actions get their final scan.
    fn abort_now(&mut self) {
        let lost: Vec<(TokenId, String, String)> = self
            .tokens
            .iter()
            .filter_map(|(id, t)| {
                let agent = t.agent.clone()?;
                let reachable = self.agents.get(&agent).is_some_and(|a| a.alive);
                (!reachable).then(|| (*id, agent, self.token_at(*id)))
            })
            .collect();
        for (id, agent, at) in lost {
            let alarm = self.alarm(
                &agent,
                format!("token {id} (at step {at}) abandoned: `{agent}` could not be told of the abort"),
            );
            let run = self.run;
            self.untold.entry(agent).or_insert_with(|| (run, Vec::new())).1.extend(alarm);
        }
        self.end_segments();
        if let Some(next) = self.run_state.when_done() {
            self.change_state(next);
        }
    }

    /// Ends every segment: agents forget the run's tokens (`ToAgent::Abort`: skills cancelled, final scans), the
    /// coordinator's engine leaves every step with its actions' final scan, and no token is left.
    fn end_segments(&mut self) {
        let told: Vec<String> =
            self.agents.iter().filter(|(_, a)| a.alive && (a.joined || a.tokens > 0)).map(|(n, _)| n.clone()).collect();
        for agent in told {
            self.send(agent, ToAgent::Abort { run: self.run });
        }
        if let Err(e) = self.engine.abort(self.now_ms) {
            self.log(Level::Error, format!("abort refused: {e}"));
        }
        self.drain_engine();
        for (_, tok) in std::mem::take(&mut self.tokens) {
            if let Some(a) = tok.agent.and_then(|a| self.agents.get_mut(&a)) {
                a.tokens = a.tokens.saturating_sub(1);
            }
        }
        self.by_segment.iter_mut().for_each(|g| *g = None);
        self.waiting.clear();
        self.acks.clear();
    }

    /// The run ended by an operator: stopped or aborted.
    pub fn is_ended_by_operator(&self) -> bool {
        matches!(self.run_state, State::Stopped | State::Aborted)
    }

    /// Whether `agent` is a name this run knows — a step is placed on it, or an agent of that name was heard (any
    /// role-holder too) — and, if not, a refusal with the nearest known name: a typo must not answer "holding"
    /// while the robot it meant carries on.
    fn known_agent(&self, agent: &str) -> Result<(), String> {
        let mut known: BTreeSet<&str> = self.agents.keys().map(String::as_str).collect();
        known.extend(self.layout.placement.iter().filter_map(|p| match p {
            Placement::Agent(a) => Some(a.as_str()),
            Placement::Coordinator | Placement::Role(_) => None,
        }));
        if known.contains(agent) {
            return Ok(());
        }
        let names: Vec<&str> = known.iter().copied().collect();
        let hint = crate::front::pragma::nearest(agent, names.iter().copied())
            .map_or(String::new(), |k| format!("did you mean `{k}`? "));
        let listed = if names.is_empty() { "none yet".to_string() } else { names.join(", ") };
        Err(format!(
            "no agent `{agent}` in this run: no step is placed on it and no agent of that name was heard; {hint}the run's \
             agents: {listed}"
        ))
    }

    /// The parts of the run held while the rest goes on: agents by name, then steps.
    pub fn partial_holds(&self) -> Vec<String> {
        let agents = self.partial.agents.iter().map(|a| format!("agent {a}"));
        let steps = self.partial.steps.iter().map(|s| format!("step {}", self.program.steps[s.index()].name));
        agents.chain(steps).collect()
    }
}

/// The most agents held by name at once (each must be one the run knows): the set stays small.
const HELD_AGENTS_MAX: usize = 256;

fn parse_alarm(text: &str) -> Result<AlarmId, String> {
    text.trim()
        .trim_start_matches('#')
        .parse::<u64>()
        .map(AlarmId)
        .map_err(|_| format!("`{text}` is not an alarm id: give the number `baton status` shows, or `all`"))
}
