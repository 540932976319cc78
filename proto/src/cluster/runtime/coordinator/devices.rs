//! Devices: which bound devices an agent cannot reach, traced as `device_down` and `device_up`.

use std::collections::BTreeMap;

use crate::cluster::runtime::Level;
use crate::cluster::wire::DeviceReport;
use crate::exec::trace::{TraceEvent, TraceRecord};

use super::Coordinator;

impl Coordinator {
    /// A device report as it would apply (its messages cut to `DEVICE_MESSAGE_CHARS_MAX`, each binding once, as
    /// `handle_devices` keeps them); `None` when it would not apply, and then it is not journaled.
    pub(super) fn admit_devices(&self, report: &DeviceReport) -> Option<DeviceReport> {
        if report.run != self.run {
            return None;
        }
        let agent = self.agents.get(&report.agent)?;
        if agent.incarnation != report.incarnation || !agent.alive || report.seq <= agent.devices_seq {
            return None;
        }
        let mut down: BTreeMap<u32, String> = BTreeMap::new();
        for d in &report.down {
            let ours = self.layout.io.get(d.binding as usize).is_some_and(|b| b.agent == report.agent);
            if !ours {
                return None;
            }
            down.insert(d.binding, d.message.chars().take(crate::limits::DEVICE_MESSAGE_CHARS_MAX).collect());
        }
        let down = down.into_iter().map(|(binding, message)| crate::cluster::wire::DeviceDown { binding, message });
        Some(DeviceReport { down: down.collect(), ..report.clone() })
    }

    /// Which of its bound devices an agent cannot reach. Each change is a trace record, `device_down` or
    /// `device_up`, named after the variable, and a log line; the variable keeps its value meanwhile.
    pub(super) fn handle_devices(&mut self, now_ms: u64, report: DeviceReport) {
        self.advance(now_ms);
        if report.run != self.run {
            return self.drop_msg(format!("device report from `{}` for another run dropped", report.agent));
        }
        let Some(agent) = self.agents.get(&report.agent) else {
            return self.drop_msg(format!("device report from unknown agent `{}` dropped", report.agent));
        };
        if agent.incarnation != report.incarnation || !agent.alive {
            return self.drop_msg(format!(
                "device report from `{}` dropped: it comes from another process than the agent's current one",
                report.agent
            ));
        }
        if report.seq <= agent.devices_seq {
            return;
        }
        let mut down = BTreeMap::new();
        for d in report.down {
            let ours = self.layout.io.get(d.binding as usize).is_some_and(|b| b.agent == report.agent);
            if !ours {
                return self.drop_msg(format!(
                    "device report from `{}` dropped: binding {} is not one of its own",
                    report.agent, d.binding
                ));
            }
            down.insert(d.binding, d.message.chars().take(crate::limits::DEVICE_MESSAGE_CHARS_MAX).collect());
        }
        let Some(agent) = self.agents.get_mut(&report.agent) else { return };
        agent.devices_seq = report.seq;
        let before = std::mem::replace(&mut agent.devices_down, down.clone());
        let name = report.agent;
        for (b, why) in &down {
            if !before.contains_key(b) {
                let binding = &self.layout.io[*b as usize];
                let mut rec = TraceRecord::new(self.now_ms, TraceEvent::DeviceDown, &binding.name);
                rec.agent = Some(name.clone());
                rec.message = Some(format!("{}: {why}", binding.device()));
                let text = format!(
                    "agent `{name}` cannot reach the device of `{}` ({}): {why}; `{}` keeps its value {}",
                    binding.name,
                    binding.device(),
                    binding.name,
                    self.engine.value(binding.var)
                );
                self.trace(rec);
                if let Some(id) = self.alarm(&name, text) {
                    self.device_alarms.insert((name.clone(), *b), id);
                }
            }
        }
        for b in before.keys().filter(|b| !down.contains_key(b)) {
            let binding = &self.layout.io[*b as usize];
            let mut rec = TraceRecord::new(self.now_ms, TraceEvent::DeviceUp, &binding.name);
            rec.agent = Some(name.clone());
            rec.message = Some(binding.device());
            let text = format!("agent `{name}` reaches the device of `{}` again ({})", binding.name, binding.device());
            self.trace(rec);
            self.log(Level::Info, text);
            if let Some(id) = self.device_alarms.remove(&(name.clone(), *b)) {
                let changes = self.alarms.cause_gone(id);
                self.alarm_changes(changes);
            }
        }
    }
}
