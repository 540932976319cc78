//! `baton ctl`: an operator's command to a running chart.

use std::process::ExitCode;

use super::common::{block_on, EXIT_INVALID};

/// The arguments of `baton ctl`.
#[derive(clap::Args)]
pub struct Ctl {
    #[command(flatten)]
    pub reach: super::common::Reach,
    /// The run, by its id as `baton status` lists it (or the start of it).
    #[arg(long, value_name = "ID")]
    pub run: Option<String>,
    /// start (a run begun with --wait-start), hold, unhold, suspend, unsuspend, stop, abort, clear, reset
    /// (PackML's commands; clear and reset for a run begun with --stay); mode auto|step|manual; confirm or
    /// confirm TRANSITION (step mode); force TRANSITION, activate STEP, deactivate STEP, move FROM TO (manual mode); ack
    /// ALARM_ID|all; shelve ALARM_ID --for DURATION [--reason TEXT]; unshelve ALARM_ID.
    #[arg(value_name = "COMMAND")]
    pub command: String,
    /// What the command is about: the mode, a transition, a step, or an alarm's id (or `all`).
    #[arg(value_name = "TARGET")]
    pub target: Option<String>,
    /// move: the step the token goes to.
    #[arg(value_name = "TO")]
    pub to: Option<String>,
    /// hold / unhold only the branches on this agent; the rest of the run goes on.
    #[arg(long, value_name = "NAME")]
    pub agent: Option<String>,
    /// hold / unhold only the branch that holds this step.
    #[arg(long, value_name = "STEP")]
    pub step: Option<String>,
    /// shelve: for how long (`30s`, `5m`, `1h`, or milliseconds).
    #[arg(long = "for", value_name = "DURATION", value_parser = parse_duration_ms)]
    pub for_ms: Option<u64>,
    /// Why, in your words: it goes to the trace, the journal and the Rerun log.
    #[arg(long, value_name = "TEXT", default_value = "")]
    pub reason: String,
    /// ack: a comment kept with the acknowledgement (the same as --reason).
    #[arg(long, value_name = "TEXT")]
    pub comment: Option<String>,
    /// Once the command is taken, wait (at most DURATION, 10 minutes if not given) until the run has done what it
    /// leads to — `hold` until the run is held (its running motions finished), `stop` until it is stopped — and
    /// say the state it reached.
    #[arg(long, value_name = "DURATION", num_args = 0..=1, default_missing_value = "10m", value_parser = parse_duration_ms)]
    pub wait: Option<u64>,
}

impl Ctl {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let request = baton_proto::cluster::wire::CtlRequest {
            command: self.command.to_ascii_lowercase(),
            target: self.target,
            agent: self.agent,
            step: self.step,
            for_ms: self.for_ms,
            to: self.to,
            reason: self.comment.unwrap_or(self.reason),
            // The coordinator records the name the request's key gives (`client::sender`).
            by: crate::client::sender(self.reach.zenoh_config.as_deref()),
            user: None,
        };
        let (connect, run, file, wait) = (self.reach.connect, self.run, self.reach.zenoh_config, self.wait);
        block_on(async move {
            let taken = crate::client::ctl(&connect, file.as_deref(), run.as_deref(), request).await?;
            if let (true, Some(limit_ms)) = (taken, wait) {
                let limit = std::time::Duration::from_millis(limit_ms);
                crate::client::wait_settled(&connect, file.as_deref(), run.as_deref(), limit).await?;
            }
            Ok(if taken { ExitCode::SUCCESS } else { ExitCode::from(EXIT_INVALID) })
        })
    }
}

/// `30s`, `5m`, `1h`, `250ms`, or a number of milliseconds.
pub(super) fn parse_duration_ms(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let (digits, unit) = t.split_at(t.find(|c: char| !c.is_ascii_digit()).unwrap_or(t.len()));
    let n: u64 = digits.parse().map_err(|_| format!("`{text}` is not a duration: give 30s, 5m, 1h or milliseconds"))?;
    let factor = match unit {
        "" | "ms" => 1,
        "s" => 1_000,
        "m" | "min" => 60_000,
        "h" => 3_600_000,
        _ => return Err(format!("`{text}`: unknown unit `{unit}` (ms, s, m, h)")),
    };
    n.checked_mul(factor).ok_or_else(|| format!("`{text}` is too long"))
}

#[cfg(test)]
mod tests {
    #[test]
    fn durations_read_as_people_write_them() {
        assert_eq!(super::parse_duration_ms("30s"), Ok(30_000));
        assert_eq!(super::parse_duration_ms("5m"), Ok(300_000));
        assert_eq!(super::parse_duration_ms("250"), Ok(250));
        assert_eq!(super::parse_duration_ms("2h"), Ok(7_200_000));
        assert!(super::parse_duration_ms("soon").is_err());
        assert!(super::parse_duration_ms("3d").is_err());
    }
}
