//! `baton set` and `baton status`: one-shot clients of running charts, over Zenoh queries.

use std::path::Path;
use std::time::Duration;

use anyhow::{anyhow, bail};
use baton_proto::dist::keys;
use baton_proto::dist::netconfig::NetConfig;
use baton_proto::dist::wire::{self, SetReply, SetRequest, StatusReport};
use zenoh::Session;

const QUERY_TIMEOUT: Duration = Duration::from_secs(3);

async fn open(connect: &[String], file: Option<&Path>) -> anyhow::Result<Session> {
    let net = NetConfig::client(connect, false);
    let config = crate::zconf::load(&net, file)?;
    zenoh::open(config).await.map_err(|e| anyhow!("cannot reach a router at {}: {e}", connect.join(", ")))
}

/// Replies of every running chart to a query on `key`, decoded; undecodable ones are reported and skipped.
async fn ask<T: serde::de::DeserializeOwned>(
    session: &Session,
    key: String,
    payload: Option<Vec<u8>>,
) -> anyhow::Result<Vec<T>> {
    let mut get = session.get(key).timeout(QUERY_TIMEOUT);
    if let Some(p) = payload {
        get = get.payload(p);
    }
    let replies = get.await.map_err(|e| anyhow!("{e}"))?;
    let mut out = Vec::new();
    while let Ok(reply) = replies.recv_async().await {
        match reply.result() {
            Ok(sample) => match wire::decode(&sample.payload().to_bytes()) {
                Ok(v) => out.push(v),
                Err(e) => eprintln!("warning: an unreadable reply from {}: {e}", sample.key_expr()),
            },
            Err(e) => eprintln!("warning: an error reply: {e:?}"),
        }
    }
    Ok(out)
}

/// A command-line value: JSON (`true`, `42`, `1.5`) or else a string (`T#2s`).
pub fn parse_assignment(text: &str) -> Result<(String, serde_json::Value), String> {
    let (name, value) = text.split_once('=').ok_or_else(|| format!("`{text}` is not NAME=VALUE"))?;
    let name = name.trim();
    if name.is_empty() {
        return Err(format!("`{text}` has no variable name"));
    }
    let value = value.trim();
    let json = serde_json::from_str(value).unwrap_or_else(|_| serde_json::Value::String(value.to_string()));
    Ok((name.to_string(), json))
}

/// Sets an input of every chart running behind the router; true when at least one took it.
pub async fn set(
    connect: &[String],
    file: Option<&Path>,
    name: &str,
    value: serde_json::Value,
) -> anyhow::Result<bool> {
    let session = open(connect, file).await?;
    let replies = set_on(&session, name, value).await?;
    session.close().await.map_err(|e| anyhow!("{e}"))?;
    if replies.is_empty() {
        bail!("no running chart answered behind {} (or the router's access control refused you)", connect.join(", "));
    }
    for r in &replies {
        if r.ok {
            println!("{}: {}", r.chart, r.message);
        } else {
            eprintln!("{}: {}", r.chart, r.message);
        }
    }
    Ok(replies.iter().any(|r| r.ok))
}

/// Sets an input of every chart running behind `session`'s router: their replies.
pub async fn set_on(session: &Session, name: &str, value: serde_json::Value) -> anyhow::Result<Vec<SetReply>> {
    let request = wire::encode(&SetRequest { name: name.to_string(), value });
    ask(session, keys::set_any_run(), Some(request)).await
}

pub async fn status(connect: &[String], file: Option<&Path>, json: bool) -> anyhow::Result<()> {
    let session = open(connect, file).await?;
    let mut reports: Vec<StatusReport> = ask(&session, keys::status_any_run(), None).await?;
    session.close().await.map_err(|e| anyhow!("{e}"))?;
    if reports.is_empty() {
        bail!("no running chart answered behind {}", connect.join(", "));
    }
    reports.sort_by(|a, b| a.chart.cmp(&b.chart));
    if json {
        for r in &reports {
            println!("{}", serde_json::to_string(r)?);
        }
        return Ok(());
    }
    for r in &reports {
        println!("chart `{}` (run {}, version {}), running for {} ms", r.chart, r.run.key(), r.hash.0, r.t_ms);
        println!("  active steps:");
        for s in &r.active_steps {
            let at = s.agent.as_ref().map_or(String::new(), |a| format!(" on `{a}`"));
            println!("    {} ({}){at}", s.name, s.placement);
        }
        println!("  tokens in flight: {}", r.tokens.len());
        for t in &r.tokens {
            let at = t.agent.as_ref().map_or("waiting for an agent".to_string(), |a| format!("on `{a}`"));
            let paused = if t.paused { " (paused: its agent is lost)" } else { "" };
            println!("    {} epoch {} at {} {at}, since {} ms{paused}", t.token, t.epoch, t.entry, t.since_ms);
        }
        println!("  live agents: {}", r.agents.len());
        for a in &r.agents {
            let roles = if a.roles.is_empty() { String::new() } else { format!(" roles {}", a.roles.join(", ")) };
            println!("    {}{roles}, {} token(s)", a.name, a.tokens);
            for d in &a.devices_down {
                println!(
                    "      cannot reach the device of `{}` ({}): {}; it keeps its value",
                    d.var, d.device, d.message
                );
            }
        }
    }
    Ok(())
}
