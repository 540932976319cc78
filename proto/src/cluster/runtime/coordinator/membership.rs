//! Membership: agents that come up (with who they are and which process), go down, collide on a name, and the peers
//! table every agent is told.

use std::collections::BTreeMap;

use crate::cluster::layout::Placement;
use crate::cluster::runtime::{Level, COORDINATOR};
use crate::cluster::wire::{AgentInfo, Peer, ToAgent, TokenId};
use crate::exec::trace::{TraceEvent, TraceRecord};
use crate::limits::AGENTS_MAX;

use super::state::AgentState;
use super::{Coordinator, LossPolicy};

impl Coordinator {
    /// The writers agents may take variable updates from, as the agents tracked now say; when that changed, every
    /// agent taking part in the run hears the new table.
    pub(super) fn refresh_peers(&mut self) {
        let agents: Vec<Peer> = self
            .agents
            .iter()
            .filter(|(name, a)| {
                self.writer_names.contains(*name) || a.roles.iter().any(|r| self.writer_roles.contains(r))
            })
            .map(|(name, a)| Peer { name: name.clone(), incarnation: a.incarnation, roles: a.roles.clone() })
            .collect();
        if agents == self.peers.agents {
            return;
        }
        self.peers.seq += 1;
        self.peers.agents = agents;
        let joined: Vec<String> =
            self.agents.iter().filter(|(_, a)| a.joined && a.alive && !a.conflict).map(|(n, _)| n.clone()).collect();
        for name in joined {
            let msg = ToAgent::Peers { run: self.run, peers: self.peers.clone() };
            self.send(name, msg);
        }
    }

    /// This coordinator started again from its journal (replayed up to here): nothing it knew about the agents
    /// still holds until each says so. Their tokens stay theirs, unconfirmed: an agent that comes back with the
    /// token keeps it (and is asked for its unacknowledged reports), one that lacks it gets the dispatch again in
    /// the same epoch, and a restarted one runs the segment again in a new epoch. Variables are published again.
    pub fn handle_recover(&mut self, now_ms: u64) {
        self.advance(now_ms);
        for a in self.agents.values_mut() {
            a.recovering = true;
        }
        self.recovered_ms = Some(self.now_ms);
        for t in self.tokens.values_mut() {
            if t.agent.is_some() {
                t.confirmed = false;
            }
        }
        self.acks.clear();
        self.published.iter_mut().for_each(|p| *p = None);
        let out = self.tokens.len();
        let message = format!("started again from the journal with {out} token(s) out");
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Recover, &self.program.name);
        rec.message = Some(message.clone());
        self.trace(rec);
        self.log(Level::Info, message);
    }

    /// An agent announced itself (or came back). Tokens waiting for it leave now.
    pub fn handle_agent_up(&mut self, now_ms: u64, info: AgentInfo) {
        self.advance(now_ms);
        let valid = |n: &str| crate::cluster::keys::is_valid_name(n) && n != COORDINATOR;
        if !valid(&info.name) || !info.roles.iter().all(|r| crate::cluster::keys::is_valid_name(r)) {
            self.drop_msg(format!("agent announcement with an invalid name or role ignored: {:?}", info.name));
            return;
        }
        if !self.agents.contains_key(&info.name) && self.agents.len() >= AGENTS_MAX {
            self.drop_msg(format!("agent `{}` ignored: already tracking {AGENTS_MAX} agents", info.name));
            return;
        }
        let name = info.name.clone();
        if self.agents.get(&name).is_some_and(|a| a.gone_at_ms.is_some() && a.incarnation != info.incarnation) {
            // Its process went and another came within the grace: the one that went is lost, as it would have
            // been without the grace (what it held runs again, or waits, as the loss policy says).
            self.lose_agent(&name);
        }
        let entry = self.agents.entry(name.clone()).or_insert_with(|| AgentState::new(info.incarnation, info.lease_ms));
        let was_alive = entry.alive;
        let recovering = std::mem::take(&mut entry.recovering);
        let restarted = entry.incarnation != info.incarnation;
        let old_incarnation = entry.incarnation;
        let was_conflict = std::mem::take(&mut entry.conflict);
        entry.roles = info.roles.clone();
        entry.lease_ms = info.lease_ms;
        entry.skills = info
            .skills
            .as_ref()
            .filter(|s| s.len() <= crate::limits::SKILLS_ANNOUNCED_MAX)
            .map(|s| s.iter().cloned().collect());
        // Back within its grace: never lost.
        entry.gone_at_ms = None;
        entry.alive = true;
        entry.incarnation = info.incarnation;
        if restarted {
            // The new process numbers its device reports from 1; what it cannot reach it says when it joins. It
            // knows nothing of the run yet.
            entry.devices_seq = 0;
            entry.joined = false;
        }
        if was_conflict {
            self.log(Level::Info, format!("agent `{name}` answers alone again"));
        }
        if restarted {
            // Its numbers start again: what the old process still sends is late.
            self.var_writes.retire(name.clone(), old_incarnation);
        }
        self.refresh_peers();
        if !was_alive {
            let mut rec = TraceRecord::new(self.now_ms, TraceEvent::AgentUp, &name);
            rec.agent = Some(name.clone());
            self.trace(rec);
            let roles =
                if info.roles.is_empty() { String::new() } else { format!(" (roles: {})", info.roles.join(", ")) };
            self.log(Level::Info, format!("agent `{name}` is live{roles}"));
        }
        // Said once the agent is live, before anything is sent to it.
        self.check_skills_of(&name);
        let sync = self.settle_tokens_of(&name, &info, recovering);
        if sync {
            self.send(name.clone(), ToAgent::Sync { run: self.run });
        }
        // An agent that connects bound variables takes part in the run from the start, tokens or not.
        if (!was_alive || restarted) && self.layout.io.iter().any(|b| b.agent == name) {
            let msg = self.join_msg(&name);
            self.send(name.clone(), msg);
        }
        // Back after an abort it could not be told of: it is told now.
        self.tell_of_end(&name);
        self.drop_stale_of(&name, &info);
        self.dispatch_waiting();
        self.settle();
    }

    /// The tokens of agent `name` that were paused (it was lost) or unconfirmed (this coordinator restarted), now
    /// that it announced itself (`info`): if it is the same process and holds the token, it keeps it and sends its
    /// unacknowledged reports now; if it lacks it, the dispatch goes again in the same epoch; if it restarted, the
    /// segment's progress died with the old process and it runs again from its first step, in a new epoch.
    /// Whether the agent is to be asked for its reports and values (`ToAgent::Sync`).
    fn settle_tokens_of(&mut self, name: &str, info: &AgentInfo, recovering: bool) -> bool {
        let name = name.to_string();
        let mut settle: Vec<TokenId> = self
            .tokens
            .iter()
            // A new process of the agent lost whatever the old one held, even if this coordinator never saw the
            // old one go (a restart faster than the liveliness token's deletion).
            .filter(|(_, t)| t.paused || !t.confirmed || t.incarnation != info.incarnation)
            .filter(|(_, t)| t.agent.as_deref() == Some(name.as_str()))
            .map(|(id, _)| *id)
            .collect();
        settle.sort_unstable();
        let run = self.run;
        // A coordinator that started again asks every agent for its unacknowledged reports and its values: what it
        // took before it died may not have been durable.
        let mut sync = recovering;
        for id in settle {
            let Some(tok) = self.tokens.get_mut(&id) else { continue };
            let entry = self.program.steps[tok.entry.index()].name.clone();
            // Compared with the process the token went to, not the last one announced: under `fail` the token stays
            // with the process that lost it, and nothing of it ever goes to the new one.
            if tok.incarnation != info.incarnation {
                if self.policy == LossPolicy::Fail {
                    let why = format!("agent `{name}` restarted while holding the token of step `{entry}`");
                    self.alarm(&name, why.clone());
                    self.failure.get_or_insert(why);
                    continue;
                }
                self.alarm(
                    &name,
                    format!(
                    "agent `{name}` came back restarted: the segment of step `{entry}` runs again from its first step"
                ),
                );
                self.restart_on(id, Some(name.clone()));
                continue;
            }
            tok.paused = false;
            tok.reassign_at_ms = None;
            tok.confirmed = true;
            let epoch = tok.epoch;
            if info.held.iter().any(|h| h.run == run && h.token == id && h.epoch == epoch) {
                sync = true;
                let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Resume, &entry);
                rec.agent = Some(name.clone());
                rec.token = Some(id.to_string());
                rec.epoch = Some(epoch);
                rec.message = Some("still held by the agent".to_string());
                self.trace(rec);
            } else {
                self.send_token(id, TraceEvent::Resume);
            }
        }
        sync
    }

    /// What agent `name` still holds (`info`) of an older epoch (its segment moved on while it was away) or of a
    /// token that is over: it must not run it a moment longer.
    fn drop_stale_of(&mut self, name: &str, info: &AgentInfo) {
        let run = self.run;
        let mut stale: Vec<(TokenId, u32)> = info
            .held
            .iter()
            .filter(|h| h.run == run)
            .filter(|h| match self.tokens.get(&h.token) {
                Some(t) => t.epoch != h.epoch || t.agent.as_deref() != Some(name),
                None => {
                    !self.finished.get(&h.token).is_some_and(|(epoch, _, agent)| *epoch == h.epoch && agent == name)
                }
            })
            .map(|h| (h.token, h.epoch))
            .collect();
        stale.sort_unstable();
        for (token, epoch) in stale {
            self.send(name.to_string(), ToAgent::Drop { run, token, epoch });
        }
    }

    /// The tokens that waited for an agent go to one now, if one can take them.
    fn dispatch_waiting(&mut self) {
        let waiting = std::mem::take(&mut self.waiting);
        for id in waiting {
            let Some(tok) = self.tokens.get(&id) else { continue };
            match self.choose_agent(tok.segment) {
                Some(agent) => {
                    self.assign(id, agent);
                    self.emit_dispatch_or_wait(id);
                }
                None => self.waiting.push(id),
            }
        }
    }

    /// More than one process answered to agent `name` (a copied service file, an old process that lingers):
    /// each would run what is sent to the name, so nothing is dispatched to it, its tokens are held, and an
    /// alarm says so, until one process answers alone (`handle_agent_up`).
    pub fn handle_agent_conflict(&mut self, now_ms: u64, name: &str, processes: usize) {
        self.advance(now_ms);
        if !crate::cluster::keys::is_valid_name(name) {
            return self.drop_msg(format!("agent conflict with an invalid name ignored: {name:?}"));
        }
        if !self.agents.contains_key(name) && self.agents.len() >= AGENTS_MAX {
            return self.drop_msg(format!("agent `{name}` ignored: already tracking {AGENTS_MAX} agents"));
        }
        let agent = self.agents.entry(name.to_string()).or_insert_with(|| AgentState::new(uuid::Uuid::nil(), 0));
        if std::mem::replace(&mut agent.conflict, true) {
            return;
        }
        for t in self.tokens.values_mut().filter(|t| t.agent.as_deref() == Some(name)) {
            t.paused = true;
        }
        self.refresh_peers();
        self.alarm(name, format!(
            "{processes} processes answer as agent `{name}`: nothing is sent to `{name}`, and its tokens are held, until one of them stops"
        ));
        self.settle();
    }

    /// An agent's liveliness token is gone (killed: at once; hung or cut off: after its lease). Its tokens are
    /// paused, reassigned or fail the run, as the loss policy says.
    /// The agent's liveliness token went: it is lost unless it comes back within its grace (`loss_grace_ms`), when
    /// nothing happened; the next cycle after the grace loses it (`lose_gone_agents`).
    pub fn handle_agent_down(&mut self, now_ms: u64, name: &str) {
        self.advance(now_ms);
        let Some(agent) = self.agents.get_mut(name) else { return };
        if !agent.alive || agent.gone_at_ms.is_some() {
            return;
        }
        if crate::limits::loss_grace_ms(agent.lease_ms) == 0 {
            return self.lose_agent(name);
        }
        agent.gone_at_ms = Some(self.now_ms);
    }

    /// The agents whose token went and did not come back within their grace: lost now.
    pub(super) fn lose_gone_agents(&mut self) {
        let now = self.now_ms;
        let due: Vec<String> = self
            .agents
            .iter()
            .filter(|(_, a)| a.gone_at_ms.is_some_and(|t| now >= t + crate::limits::loss_grace_ms(a.lease_ms)))
            .map(|(n, _)| n.clone())
            .collect();
        for name in due {
            self.lose_agent(&name);
        }
    }

    /// When the next agent whose token went is lost, if it does not come back.
    pub(super) fn next_loss_ms(&self) -> Option<u64> {
        self.agents.values().filter_map(|a| Some(a.gone_at_ms? + crate::limits::loss_grace_ms(a.lease_ms))).min()
    }

    /// The agent is lost: its tokens are paused, reassigned or fail the run, as the loss policy says.
    pub(super) fn lose_agent(&mut self, name: &str) {
        let Some(agent) = self.agents.get_mut(name) else { return };
        if !agent.alive {
            return;
        }
        agent.alive = false;
        agent.gone_at_ms = None;
        let lease_ms = agent.lease_ms;
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::AgentLost, name);
        rec.agent = Some(name.to_string());
        self.trace(rec);
        let mut held: Vec<TokenId> =
            self.tokens.iter().filter(|(_, t)| t.agent.as_deref() == Some(name)).map(|(id, _)| *id).collect();
        held.sort_unstable();
        if held.is_empty() {
            self.log(Level::Info, format!("agent `{name}` is gone; it held no token"));
        }
        for id in held {
            let at = self.token_at(id);
            match self.policy {
                LossPolicy::Pause => {
                    if let Some(t) = self.tokens.get_mut(&id) {
                        t.paused = true;
                    }
                    self.alarm(
                        name,
                        format!("agent `{name}` lost holding the token of step {at}: paused until it comes back"),
                    );
                }
                LossPolicy::Reassign => {
                    // The agent stops the segment's skills once it has lost its router for long enough; only then
                    // may another agent start it.
                    let margin = crate::limits::fence_margin_ms(lease_ms);
                    if let Some(t) = self.tokens.get_mut(&id) {
                        t.paused = true;
                        t.reassign_at_ms = Some(self.now_ms + margin);
                    }
                    self.alarm(name, format!(
                        "agent `{name}` lost holding the token of step {at}: reassigned, from its first step, in {margin} ms unless it comes back"
                    ));
                }
                LossPolicy::Fail => {
                    let why = format!("agent `{name}` was lost holding the token of step {at}");
                    self.alarm(name, why.clone());
                    self.failure.get_or_insert(why);
                }
            }
        }
        self.forget_if_gone(name);
        self.settle();
    }

    /// An agent that is gone and holds no token is forgotten: if it comes back, it is a new one. So the agents
    /// tracked are the live ones and the lost ones with a token, however many names come and go.
    pub(super) fn forget_if_gone(&mut self, name: &str) {
        let gone = self.agents.get(name).is_some_and(|a| !a.alive);
        if gone && !self.tokens.values().any(|t| t.agent.as_deref() == Some(name)) {
            self.agents.remove(name);
            self.acks.remove(name);
            self.refresh_peers();
        }
    }

    /// Whether `agent` may be sent `segment`: it has every skill the segment's steps run, or did not say which it
    /// has.
    pub(super) fn has_skills_for(&self, agent: &str, segment: usize) -> bool {
        let Some(has) = self.agents.get(agent).and_then(|a| a.skills.as_ref()) else { return true };
        crate::cluster::skills::lacking(&self.program, &self.layout, segment, has).is_empty()
    }

    /// The skills `agent` lacks to run `segment`, as words: "skill `x` (action `A`)".
    pub(super) fn skills_lacked(&self, agent: &str, segment: usize) -> String {
        let Some(has) = self.agents.get(agent).and_then(|a| a.skills.as_ref()) else { return String::new() };
        let lacking = crate::cluster::skills::lacking(&self.program, &self.layout, segment, has);
        let words: Vec<String> =
            lacking.iter().map(|(skill, action, _)| format!("skill `{skill}` (action `{action}`)")).collect();
        words.join(", ")
    }

    /// The skills `agent` lacks for the segments its placement would send it, each with the action that binds it
    /// and the step it runs at: one alarm per skill, raised when it announces itself (before any token is sent it)
    /// and returned to normal when a process of it announces the skill — not when it goes: what it lacked still
    /// keeps its steps from running.
    pub(super) fn check_skills_of(&mut self, agent: &str) {
        let mut lacking: BTreeMap<String, String> = BTreeMap::new();
        let has = self.agents.get(agent).and_then(|a| a.skills.clone());
        if let Some(has) = &has {
            for (g, seg) in self.layout.segments.iter().enumerate() {
                if !self.serves(agent, &seg.placement) {
                    continue;
                }
                for (skill, action, step) in crate::cluster::skills::lacking(&self.program, &self.layout, g, has) {
                    lacking.entry(skill.to_string()).or_insert_with(|| format!("action `{action}` of step `{step}`"));
                }
            }
        }
        let gone: Vec<(String, String)> =
            self.skill_alarms.keys().filter(|(a, s)| a == agent && !lacking.contains_key(s)).cloned().collect();
        for key in gone {
            if let Some(id) = self.skill_alarms.remove(&key) {
                if has.is_some() {
                    self.log(Level::Info, format!("agent `{agent}` has skill `{}` now", key.1));
                }
                let changes = self.alarms.cause_gone(id);
                self.alarm_changes(changes);
            }
        }
        let offered = has.map(|h| h.into_iter().collect::<Vec<_>>().join(", ")).unwrap_or_default();
        for (skill, user) in lacking {
            let key = (agent.to_string(), skill.clone());
            if self.skill_alarms.contains_key(&key) {
                continue;
            }
            let names = if offered.is_empty() { "none".to_string() } else { offered.clone() };
            let text = format!(
                "agent `{agent}` has no skill `{skill}`, which {user} runs: nothing of that step is sent to it (its \
                 skills: {names})"
            );
            if let Some(id) = self.alarm(agent, text) {
                self.skill_alarms.insert(key, id);
            }
        }
    }

    pub(super) fn serves(&self, agent: &str, placement: &Placement) -> bool {
        match placement {
            Placement::Coordinator => false,
            Placement::Agent(a) => a == agent,
            Placement::Role(r) => self.agents.get(agent).is_some_and(|s| s.roles.iter().any(|x| x == r)),
        }
    }
}
