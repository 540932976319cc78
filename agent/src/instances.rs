//! Many agents in one process, so that one machine stands up hundreds for a benchmark or a test (`baton-agent
//! --instances N`, `baton bench`). One agent per robot stays the model: a robot's agent is a process of its own,
//! whose crash or restart takes nothing else with it. Each agent here is what `run` makes — its own Zenoh session,
//! liveliness token, queryables and runs — and they share only the process's runtime, skills and connections.

use std::collections::HashSet;

use anyhow::{anyhow, bail};
use tokio::sync::watch;

use crate::host::{run_until, AgentConfig};
use crate::{Connections, Skills};

/// `count` agents like `template`, named `NAME1` … `NAMEcount` after the template's name.
pub fn configs(template: &AgentConfig, count: u32) -> Vec<AgentConfig> {
    (1..=count).map(|k| AgentConfig { name: format!("{}{k}", template.name), ..template.clone() }).collect()
}

/// Runs every agent of `configs` until the process is interrupted (Ctrl-C or SIGTERM), or until one of them fails:
/// then the others stop too, and the failure is the answer, with the agent's name.
pub async fn run_many(configs: Vec<AgentConfig>, skills: Skills, connections: Connections) -> anyhow::Result<()> {
    let mut names = HashSet::new();
    for c in &configs {
        c.validate()?;
        if !names.insert(c.name.clone()) {
            bail!("two agents of this process are named `{}`", c.name);
        }
    }
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut agents = tokio::task::JoinSet::new();
    for config in configs {
        let (skills, connections, mut stop) = (skills.clone(), connections.clone(), stop_rx.clone());
        agents.spawn(async move {
            let name = config.name.clone();
            let stopped = async move {
                // A dropped sender (the process ending) stops the agent as a signal does.
                let _ = stop.wait_for(|s| *s).await;
            };
            run_until(config, skills, connections, stopped).await.map_err(|e| anyhow!("agent `{name}`: {e:#}"))
        });
    }
    let mut signal = baton_host::Stop::new()?;
    let mut first_error = None;
    loop {
        tokio::select! {
            _ = signal.recv() => {
                let _ = stop_tx.send(true);
            }
            ended = agents.join_next() => match ended {
                None => break,
                Some(result) => {
                    let result = result.map_err(|e| anyhow!("an agent's task ended abnormally: {e}")).and_then(|r| r);
                    if let Err(e) = result {
                        let _ = stop_tx.send(true);
                        first_error.get_or_insert(e);
                    }
                }
            },
        }
    }
    first_error.map_or(Ok(()), Err)
}
