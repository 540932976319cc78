//! Devices: bound inputs written into the chart, outputs sent to their devices, and which devices cannot be reached.

use crate::cluster::bindings::IoDir;
use crate::cluster::runtime::Level;
use crate::cluster::wire::{DeviceDown, DeviceReport};
use crate::exec::engine::Input;
use crate::exec::program::VarId;
use crate::types::Value;

use super::{AgentOutput, AgentRun};

impl AgentRun {
    /// Writes what a device gave (a skill's answer, a bound input) to `var`, converted to its type as `*_TO_*`
    /// converts, then reacts.
    pub(super) fn write_from_device(&mut self, var: VarId, value: Value, what: String) {
        let ty = self.program.vars[var.index()].ty.clone();
        let value = crate::exec::stdlib::convert(value, &ty);
        if let Err(e) = self.engine.handle(Input::Set(var, value)) {
            self.log(Level::Warn, format!("{what}: {e}"));
        }
        self.settle();
    }

    /// Whether the device of binding `binding` (`Layout::io`, on this agent) can be reached: `Err` says why not.
    /// A change is logged and reported to the coordinator; a new reason while it stays down replaces the old one
    /// quietly (a device retried every second would flood the log). Meanwhile an input keeps its value.
    pub fn handle_device(&mut self, binding: usize, state: Result<(), String>) {
        let Some(b) = self.layout.io.get(binding).filter(|b| b.agent == self.name) else {
            self.dropped += 1;
            return;
        };
        let what = format!("{} `{}` ({})", if b.dir == IoDir::Input { "input" } else { "output" }, b.name, b.device());
        let (var, dir) = (b.var, b.dir);
        match state {
            Ok(()) => {
                if self.devices_down.remove(&binding).is_some() {
                    self.log(Level::Info, format!("{what}: reachable again"));
                    self.report_devices();
                }
            }
            Err(why) => {
                let why: String = why.chars().take(crate::limits::DEVICE_MESSAGE_CHARS_MAX).collect();
                if self.devices_down.insert(binding, why.clone()).is_none() {
                    let keeps = match dir {
                        IoDir::Input => format!("it keeps its value {}", self.engine.value(var)),
                        IoDir::Output => "its value goes to the device once it is back".to_string(),
                    };
                    self.log(Level::Warn, format!("{what}: {why}; {keeps}"));
                    self.report_devices();
                }
            }
        }
    }

    pub(super) fn report_devices(&mut self) {
        self.devices_seq += 1;
        let down = self
            .devices_down
            .iter()
            .map(|(b, message)| DeviceDown { binding: *b as u32, message: message.clone() })
            .collect();
        self.outbox.push_back(AgentOutput::Devices(DeviceReport {
            run: self.run,
            agent: self.name.clone(),
            incarnation: self.incarnation,
            seq: self.devices_seq,
            down,
        }));
    }

    /// Queues the output-bound variables of this agent whose value changed since they were last sent.
    pub(super) fn send_outputs(&mut self) {
        for i in 0..self.layout.io.len() {
            let b = &self.layout.io[i];
            if b.agent != self.name || b.dir != IoDir::Output {
                continue;
            }
            let value = self.engine.value(b.var);
            if self.io_sent[i].as_ref() != Some(&value) {
                self.io_sent[i] = Some(value.clone());
                self.outbox.push_back(AgentOutput::Output { binding: i, value });
            }
        }
    }
}
