//! The agent's own trace (`baton-agent --trace FILE`): what befell this process — its start, its contact with
//! the router, each skill's start, end, cancel and stop, an input refused — one JSON record per line, in the
//! format of the coordinator's trace (`baton_proto::exec::trace::TraceRecord`), with `t_ms` in Unix time and
//! `agent` naming the agent (a process of `--instances` writes all its agents' records in one file).
//!
//! The log (stderr) says the same for a person and may change its words; the trace is what a program reads.
//! It is written line by line as things happen, so that a reader following the file sees each record at once.

use std::io::Write;
use std::path::Path;
use std::sync::{Mutex, OnceLock};

use baton_proto::exec::trace::{TraceEvent, TraceRecord};

static SINK: OnceLock<Mutex<std::fs::File>> = OnceLock::new();

/// Opens `path` for this process's trace, appending to what it holds. Once per process.
pub fn open(path: &Path) -> anyhow::Result<()> {
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| anyhow::anyhow!("cannot open the trace {}: {e}", path.display()))?;
    SINK.set(Mutex::new(file)).map_err(|_| anyhow::anyhow!("the agent's trace is open already"))
}

/// Writes `record` as agent `agent`'s, stamped now; nothing when no trace is open. A record that cannot be
/// written is said once on stderr, and the agent goes on: its trace is a witness, not its state.
pub fn write(agent: &str, mut record: TraceRecord) {
    let Some(sink) = SINK.get() else { return };
    record.t_ms = baton_host::unix_ms();
    record.agent = Some(agent.to_string());
    let Ok(mut line) = serde_json::to_string(&record) else { return };
    line.push('\n');
    let Ok(mut file) = sink.lock() else { return };
    if let Err(e) = file.write_all(line.as_bytes()) {
        static SAID: std::sync::Once = std::sync::Once::new();
        SAID.call_once(|| eprintln!("warning: cannot write the agent's trace: {e}"));
    }
}

/// Writes a record of `event` of `name`, with `message`, as agent `agent`'s.
pub fn event(agent: &str, event: TraceEvent, name: &str, message: Option<String>) {
    let mut record = TraceRecord::new(0, event, name);
    record.message = message;
    write(agent, record);
}
