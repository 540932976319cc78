//! Variables: the values this agent writes, published with an update number; the values it reads, taken only from their
//! writer's current process or the coordinator, in order.

use uuid::Uuid;

use crate::cluster::layout::Placement;
use crate::cluster::runtime::{Level, COORDINATOR};
use crate::cluster::wire::{Peers, VarUpdate, VarValue};
use crate::exec::engine::Input;
use crate::exec::program::VarId;
use crate::limits::PARKED_UPDATE_BYTES_MAX;

use super::{AgentOutput, AgentRun, REFUSALS_SAID_MAX};

impl AgentRun {
    /// The coordinator's values in a dispatch or a join: the variables this agent writes only while it has not
    /// taken part in the run yet, the others as of `vars_seq` (what another agent wrote is only relayed: that
    /// agent's own updates win).
    pub(super) fn take_coordinator_values(&mut self, vars: &[VarValue], vars_seq: u64) {
        let seed = !std::mem::replace(&mut self.seeded, true);
        let coordinator = self.peers.as_ref().map_or(Uuid::nil(), |p| p.coordinator);
        for vv in vars {
            let relay =
                vv.resolve(&self.program).is_some_and(|(v, _)| self.layout.writer[v.index()] != Placement::Coordinator);
            if !self.accept_external(vv, COORDINATOR, coordinator, vars_seq, relay, seed) {
                self.dropped += 1;
            }
        }
    }

    /// Every value only this agent writes goes out again in a fresh update: a coordinator that started again from
    /// its journal, or a link that lost messages, may have missed the last ones. A role's variable is not said
    /// again: the agents of the role write it in turn, and a value said again would overwrite a newer one of
    /// another agent (the coordinator hears a role's values in reports, which are resent until acknowledged).
    pub(super) fn republish(&mut self) {
        // A process that has not taken part in the run yet holds the chart's initial values, not the run's.
        if !self.seeded {
            return;
        }
        for v in self.mine() {
            self.unreported.insert(v.0, self.engine.value(v));
        }
        let read = self.mine_read();
        if read.is_empty() {
            return;
        }
        self.vars_seq += 1;
        self.publish(read);
    }

    /// The variables only this agent writes.
    pub(super) fn mine(&self) -> Vec<VarId> {
        self.owned.iter().zip(&self.pinned).filter(|(_, &pinned)| pinned).map(|(&v, _)| v).collect()
    }

    /// The values of those that other agents read.
    pub(super) fn mine_read(&self) -> Vec<VarValue> {
        self.mine()
            .into_iter()
            .filter(|v| self.layout.read_by_agents[v.index()])
            .map(|v| VarValue::new(v, self.engine.value(v)))
            .collect()
    }

    /// Publishes `vars` as update `vars_seq`, and plans to publish the values only this agent writes again.
    pub(super) fn publish(&mut self, vars: Vec<VarValue>) {
        let update = VarUpdate {
            run: self.run,
            from: self.name.clone(),
            incarnation: self.incarnation,
            seq: self.vars_seq,
            vars,
        };
        self.outbox.push_back(AgentOutput::Vars(update));
        self.vars_resend.start(self.now_ms);
    }

    /// Publishes the values only this agent writes again, as of its last update, when that is due.
    pub(super) fn resend_vars(&mut self) {
        if !self.vars_resend.due(self.now_ms) {
            return;
        }
        let read = self.mine_read();
        if !read.is_empty() {
            let update = VarUpdate {
                run: self.run,
                from: self.name.clone(),
                incarnation: self.incarnation,
                seq: self.vars_seq,
                vars: read,
            };
            self.outbox.push_back(AgentOutput::Vars(update));
        }
    }

    /// Variables published by the coordinator or another agent; the latest update of each writer wins. An agent
    /// applies the coordinator's rules: a value is taken only from the variable's one writer (the coordinator,
    /// its agent, or an agent of its role), and only from the process of that writer the coordinator named
    /// (`Peers`). An update of a known writer's process not named yet waits for the coordinator's word; anything
    /// else is counted and dropped. `term` is the coordinator term the update came with: the coordinator's own of
    /// a lower term than the highest seen are refused, as its commands are (`take_term`); an agent's carry none.
    pub fn handle_vars(&mut self, now_ms: u64, term: u64, update: &VarUpdate) {
        if update.from == self.name || update.run != self.run {
            return;
        }
        if update.from == COORDINATOR && !self.take_term(now_ms, term, "variable update") {
            return;
        }
        if update.from != COORDINATOR && !crate::cluster::keys::is_valid_name(&update.from) {
            self.dropped += 1;
            return;
        }
        self.catch_up(now_ms);
        self.take_update(update);
        self.settle();
    }

    /// Whether `from`'s process `incarnation` is the one the coordinator named: `None` when it named none of `from`.
    pub(super) fn known_process(&self, from: &str, incarnation: Uuid) -> Option<bool> {
        let peers = self.peers.as_ref()?;
        if from == COORDINATOR {
            return Some(peers.coordinator == incarnation);
        }
        peers.agents.iter().find(|p| p.name == from).map(|p| p.incarnation == incarnation)
    }

    pub(super) fn take_update(&mut self, update: &VarUpdate) {
        let from = update.from.as_str();
        match self.known_process(from, update.incarnation) {
            Some(true) => {}
            // A new process of a writer the coordinator knows (or of an agent of a writing role it has not told
            // about yet): its values wait for the coordinator's word, unless the process was replaced already.
            None | Some(false)
                if from != COORDINATOR
                    && self.may_write(from)
                    && !self.var_writes.is_retired(from, update.incarnation) =>
            {
                return self.park(update.clone());
            }
            _ => {
                let why = if from == COORDINATOR {
                    "it claims to come from the coordinator, but from another process than the run's".to_string()
                } else if self.var_writes.is_retired(from, update.incarnation) {
                    format!("it comes from a process of `{from}` that a newer one replaced")
                } else {
                    format!("`{from}` writes none of the variables this agent reads")
                };
                return self.refuse(update, why);
            }
        }
        let mut foreign = 0;
        for vv in &update.vars {
            let ok = vv.resolve(&self.program).is_some_and(|(v, _)| self.writes(from, v));
            if !ok || !self.accept_external(vv, from, update.incarnation, update.seq, false, false) {
                foreign += 1;
            }
        }
        if foreign > 0 {
            self.refuse(
                update,
                format!("{foreign} of its values are of variables `{from}` does not write, or of the wrong type"),
            );
        }
    }

    /// Whether `from` may write a variable this agent reads: an agent placed by name on one, or any agent while a
    /// role writes one (the coordinator names the agents of a role as they come).
    pub(super) fn may_write(&self, from: &str) -> bool {
        self.layout.writer.iter().zip(&self.layout.read_by_agents).any(|(w, &read)| {
            read && match w {
                Placement::Agent(a) => a == from,
                Placement::Role(_) => true,
                Placement::Coordinator => false,
            }
        })
    }

    /// Counts a refused update, and says so once per sending process (a peer that keeps sending is not a log
    /// flood).
    pub(super) fn refuse(&mut self, update: &VarUpdate, why: String) {
        self.dropped += 1;
        let key = (update.from.clone(), update.incarnation);
        if self.refusals_said.contains(&key) {
            return;
        }
        if self.refusals_said.len() >= REFUSALS_SAID_MAX {
            self.refusals_said.pop_front();
        }
        self.refusals_said.push_back(key);
        self.log(Level::Warn, format!("variable update from `{}` refused: {why}", update.from));
    }

    /// Whether `from` is the one writer of `var`: the coordinator for its own, an agent for those placed on it or
    /// on a role the coordinator says it has.
    pub(super) fn writes(&self, from: &str, var: VarId) -> bool {
        match &self.layout.writer[var.index()] {
            Placement::Coordinator => from == COORDINATOR,
            Placement::Agent(a) => a == from,
            Placement::Role(r) => self
                .peers
                .as_ref()
                .and_then(|p| p.agents.iter().find(|p| p.name == from))
                .is_some_and(|p| p.roles.iter().any(|x| x == r)),
        }
    }

    /// Holds an update until the coordinator names its process; the oldest go first past the byte bound.
    pub(super) fn park(&mut self, update: VarUpdate) {
        let bytes = update.weight();
        if bytes > PARKED_UPDATE_BYTES_MAX {
            self.dropped += 1;
            return;
        }
        while self.parked_bytes + bytes > PARKED_UPDATE_BYTES_MAX {
            let Some(old) = self.parked.pop_front() else { break };
            self.parked_bytes -= old.weight();
            self.dropped += 1;
        }
        self.parked_bytes += bytes;
        self.parked.push_back(update);
    }

    /// Takes a value written elsewhere, unless this agent alone writes the variable (but for the coordinator's
    /// values given to a process that has not taken part yet: `seed`) or a newer write of it was taken already.
    /// Returns false for a value refused as invalid or misdirected.
    pub(super) fn accept_external(
        &mut self,
        vv: &VarValue,
        from: &str,
        incarnation: Uuid,
        seq: u64,
        relay: bool,
        seed: bool,
    ) -> bool {
        let Some((var, value)) = vv.resolve(&self.program) else { return false };
        let i = self.owned.iter().position(|&v| v == var);
        if let Some(i) = i.filter(|&i| self.pinned[i]) {
            if !seed {
                return false;
            }
            // The run's value of a variable only this agent writes: where a new process starts from.
            self.published[i] = value.clone();
            return self.engine.handle(Input::Set(var, value)).is_ok();
        }
        if !self.var_writes.accept(var.index(), from, incarnation, seq, relay) {
            return true;
        }
        if let Some(i) = i {
            // A role's variable another agent wrote: take it as already published, not as our own change.
            self.published[i] = value.clone();
        }
        self.engine.handle(Input::Set(var, value)).is_ok()
    }

    /// The coordinator says who may publish the variables this agent reads. A writer's new process retires its
    /// old one, whose late updates are refused; updates parked for a process now named apply.
    pub fn handle_peers(&mut self, now_ms: u64, peers: Peers) {
        self.catch_up(now_ms);
        self.handle_peers_table(peers);
        self.settle();
    }

    pub(super) fn handle_peers_table(&mut self, peers: Peers) {
        if self.peers.as_ref().is_some_and(|p| p.seq >= peers.seq) {
            return;
        }
        if let Some(old) = self.peers.take() {
            for gone in old.agents {
                let same = peers.agents.iter().any(|p| p.name == gone.name && p.incarnation == gone.incarnation);
                if !same {
                    self.var_writes.retire(gone.name, gone.incarnation);
                }
            }
        }
        self.peers = Some(peers);
        let parked = std::mem::take(&mut self.parked);
        self.parked_bytes = 0;
        let mut parked: Vec<VarUpdate> = parked.into_iter().collect();
        parked.sort_by_key(|u| u.seq);
        for update in parked {
            self.take_update(&update);
        }
    }
}
