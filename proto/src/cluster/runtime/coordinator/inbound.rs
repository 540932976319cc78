//! What agents send the coordinator, as one entry: a decoded message and who the network says sent it. `admit`
//! judges it before anything is recorded — one that claims another agent is refused, and of the rest, what
//! applies is what the journal keeps — and `handle_agent_message` applies it. The journal (`Journaled`) and through
//! it the coordinator's host and the simulated cluster all come this way.

use crate::cluster::wire::{FromAgent, VarUpdate};

use super::{Admitted, Coordinator};

impl Coordinator {
    /// Judges `msg` from `sender` (the agent its key names) before it is recorded: see `Admitted`.
    pub fn admit(&mut self, now_ms: u64, sender: &str, msg: &FromAgent) -> Admitted {
        if msg.claimed() != sender {
            // With access control on the router a process can publish only on its own keys; without it, this
            // keeps one agent from speaking for another by the name it writes.
            self.advance(now_ms);
            self.drop_msg(format!(
                "{} on `{sender}`'s key claiming to be from `{}` dropped",
                msg.what(),
                msg.claimed()
            ));
            return Admitted::Refused;
        }
        match msg {
            FromAgent::Report(r) if self.admit_report(r) => Admitted::Whole,
            FromAgent::Vars(u) => match self.admit_vars(u) {
                Some(kept) if kept.len() == u.vars.len() => Admitted::Whole,
                Some(kept) => Admitted::Part(FromAgent::Vars(VarUpdate { vars: kept, ..u.clone() })),
                None => Admitted::Unrecorded,
            },
            FromAgent::Devices(d) => match self.admit_devices(d) {
                Some(kept) => Admitted::Part(FromAgent::Devices(kept)),
                None => Admitted::Unrecorded,
            },
            FromAgent::Report(_) => Admitted::Unrecorded,
        }
    }

    /// Applies a message `admit` did not refuse (what it admitted, or as it came where nothing was recorded).
    pub fn handle_agent_message(&mut self, now_ms: u64, msg: FromAgent) {
        match msg {
            FromAgent::Report(r) => self.handle_report(now_ms, r),
            FromAgent::Vars(u) => self.handle_vars(now_ms, u),
            FromAgent::Devices(d) => self.handle_devices(now_ms, d),
        }
    }
}
