//! `baton set` and `baton status`: one-shot clients of running charts, over Zenoh queries.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail};
use baton_host::ZenohResult;
use baton_proto::cluster::keys;
use baton_proto::cluster::netconfig::NetConfig;
use baton_proto::cluster::wire::{self, CtlReply, CtlRequest, RunId, SetReply, SetRequest, StatusReport, WhyReport};
use zenoh::Session;

const QUERY_TIMEOUT: Duration = Duration::from_secs(3);
/// How long `--wait` asks again while no run answers before it says so: a session dropped and made again answers
/// within it.
const SILENCE_GRACE: Duration = Duration::from_secs(5);

pub async fn open(connect: &[String], file: Option<&Path>) -> anyhow::Result<Session> {
    let net = NetConfig::client(connect, false);
    let config = baton_host::zenoh_config(&net, file)?;
    match zenoh::open(config).await {
        Ok(session) => Ok(session),
        Err(_) => Err(anyhow!("{}", unreachable(connect, file.is_some()))),
    }
}

/// Why no session opened, in an operator's words (Zenoh's own error says "Timeout!" and where in its source): for
/// each endpoint, whether anything listens there at all and, if something does over plain TCP, that it may be a TLS
/// router and what to give then.
fn unreachable(connect: &[String], has_config: bool) -> String {
    let within = format!("{:.1} s", baton_proto::cluster::netconfig::CLIENT_CONNECT_TIMEOUT_MS as f64 / 1000.0);
    let mut said = vec![format!("no router answered at {} within {within}", connect.join(", "))];
    for endpoint in connect {
        let (proto, addr) = endpoint.split_once('/').unwrap_or(("", endpoint.as_str()));
        let addr = addr.split('#').next().unwrap_or(addr);
        let listening = addr
            .parse::<std::net::SocketAddr>()
            .ok()
            .map(|a| std::net::TcpStream::connect_timeout(&a, Duration::from_millis(300)).is_ok());
        match (proto, listening) {
            (_, Some(false)) => said.push(format!(
                "nothing listens at {addr}: is `baton run --listen {endpoint}` or the cell's router running there?"
            )),
            ("tcp", Some(true)) => said.push(format!(
                "something listens at {addr} but no Zenoh session opened over plain TCP: if it is a secured (TLS) \
                 router, connect with tls/{addr} and --zenoh-config with your identity's file (`baton deploy certs`)"
            )),
            ("tls" | "quic", _) if !has_config => said.push(format!(
                "{endpoint} needs --zenoh-config with the cell's CA and your certificate (`baton deploy certs`)"
            )),
            ("tls" | "quic", Some(true)) => said.push(format!(
                "something listens at {addr}: check that your --zenoh-config trusts its CA and that the router's \
                 access control lets you in"
            )),
            _ => {}
        }
    }
    said.join("; ")
}

/// Replies of every running chart to a query on `key`, decoded; undecodable ones are reported and skipped.
async fn ask<T: serde::de::DeserializeOwned>(
    session: &Session,
    key: String,
    payload: Option<Vec<u8>>,
) -> anyhow::Result<Vec<T>> {
    // Every run's reply, even if two ever came on one key.
    let mut get = baton_host::traffic::get(session, key)
        .consolidation(zenoh::query::ConsolidationMode::None)
        .timeout(QUERY_TIMEOUT);
    if let Some(p) = payload {
        get = get.payload(p);
    }
    let replies = get.await.zenoh()?;
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

fn print_why(steps: &[baton_proto::cluster::wire::StepWhy]) {
    println!("  why the active steps wait:");
    for w in steps {
        let at = w.agent.as_ref().map_or(String::new(), |a| format!(" on `{a}`"));
        let mut notes = vec![format!("active {} ms", w.active_ms)];
        if w.held {
            notes.push("held: nothing clears until it is released".into());
        }
        if w.faulted {
            notes.push("past its maximum time: its alarm waits for an acknowledgement".into());
        }
        if w.min_left_ms > 0 {
            notes.push(format!("its minimum time is {} ms away", w.min_left_ms));
        }
        println!("    {}{at} ({})", w.step, notes.join("; "));
        for s in &w.skills {
            println!("      skill of `{}` running for {} ms", s.action, s.running_ms);
        }
        for t in &w.transitions {
            let mut parts = Vec::new();
            if !t.missing.is_empty() {
                parts.push(format!("waits for {}", t.missing.join(", ")));
            }
            parts.extend(t.false_parts.iter().cloned());
            if t.waiting_confirm {
                parts.push("TRUE, waiting for `baton ctl confirm`".into());
            }
            if parts.is_empty() {
                parts.push("TRUE".into());
            }
            println!("      {}: {}", t.name, parts.join("; "));
        }
    }
}

/// Who this process sends `set` and `ctl` as, on the keys that name it (`keys::set`, `keys::ctl`): the Zenoh
/// identity it authenticates with (its user name, or its certificate's common name), which the router's access
/// control lets ask only on its own keys; else `user@host`, which nothing checks.
pub fn sender(file: Option<&Path>) -> String {
    keys::sender_name(&baton_host::zenoh_identity(file).unwrap_or_else(who))
}

/// Who this process acts for: `user@host`.
pub fn who() -> String {
    let user = std::env::var("USER").or_else(|_| std::env::var("LOGNAME")).unwrap_or_else(|_| "unknown".into());
    let mut buf = [0u8; 256];
    // SAFETY: gethostname writes at most `buf.len()` bytes into the buffer it is given.
    let host = if unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) } == 0 {
        let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
        String::from_utf8_lossy(&buf[..end]).into_owned()
    } else {
        "unknown-host".into()
    };
    format!("{user}@{host}")
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

/// Sends `payload` to one running chart's queryable `key_of(run)` — the run `run` names (its id as `baton status`
/// prints it, or a prefix of it), or the only run behind the router — and returns its replies, at least one.
/// Several runs that could be meant are refused and listed: a request must never reach a run the operator did not
/// mean.
async fn ask_one_run<T: serde::de::DeserializeOwned>(
    connect: &[String],
    file: Option<&Path>,
    run: Option<&str>,
    key_of: fn(RunId, &str) -> String,
    payload: Vec<u8>,
) -> anyhow::Result<Vec<T>> {
    let session = open(connect, file).await?;
    let result = async {
        let runs = runs_answering(&session).await?;
        let target = pick_run(&runs, run, connect)?;
        ask(&session, key_of(target, &sender(file)), Some(payload)).await
    }
    .await;
    session.close().await.zenoh()?;
    let replies = result?;
    if replies.is_empty() {
        bail!(
            "the run did not answer behind {} (it ended, or the router's access control refused you)",
            connect.join(", ")
        );
    }
    Ok(replies)
}

/// Sets an input of one running chart (`ask_one_run` picks it). True when the run took it.
pub async fn set(
    connect: &[String],
    file: Option<&Path>,
    run: Option<&str>,
    name: &str,
    value: serde_json::Value,
) -> anyhow::Result<bool> {
    let request = wire::encode(&SetRequest { name: name.to_string(), value, by: sender(file), user: None });
    let replies: Vec<SetReply> = ask_one_run(connect, file, run, keys::set, request).await?;
    for r in &replies {
        if r.ok {
            println!("{}: {}", r.chart, r.message);
        } else {
            eprintln!("{}: {}", r.chart, r.message);
        }
    }
    Ok(replies.iter().any(|r| r.ok))
}

/// Sends an operator's command to one running chart (`ask_one_run` picks it) and prints its answer: what it did,
/// or why it was refused and what is legal now. True when the run took it.
pub async fn ctl(
    connect: &[String],
    file: Option<&Path>,
    run: Option<&str>,
    request: CtlRequest,
) -> anyhow::Result<bool> {
    let replies: Vec<CtlReply> = ask_one_run(connect, file, run, keys::ctl, wire::encode(&request)).await?;
    for r in &replies {
        let legal: Vec<&str> = r.available.iter().map(|c| c.name()).collect();
        // A refusal of a PackML command says what is legal itself: not twice.
        let state = if r.message.contains("legal now") {
            format!("state {}", r.state)
        } else {
            format!("state {}; legal now: {}", r.state, legal.join(", "))
        };
        if r.ok {
            println!("{}: {} ({state})", r.chart, r.message);
        } else {
            eprintln!("{}: refused: {} ({state})", r.chart, r.message);
        }
    }
    Ok(replies.iter().any(|r| r.ok))
}

/// Waits until the run `run` names (`pick_run`) has left its acting ("-ing") state — PackML's state complete — and
/// prints the state it reached; an error after `limit`.
pub async fn wait_settled(
    connect: &[String],
    file: Option<&Path>,
    run: Option<&str>,
    limit: Duration,
) -> anyhow::Result<()> {
    let session = open(connect, file).await?;
    let settled = tokio::time::timeout(limit, async {
        let mut target = None;
        // Since when no run has answered: a run that just took the command does not vanish, but its session to the
        // router may be dropped and made again meanwhile (zenoh-link-tls drops a TLS session under load and
        // reconnects it at once: ARCHITECTURE.md, open points), and a question asked then finds nobody.
        let mut silent_since: Option<Instant> = None;
        loop {
            let runs: Vec<StatusReport> = ask(&session, keys::status_any_run(), None).await?;
            if runs.is_empty() {
                let since = *silent_since.get_or_insert_with(Instant::now);
                if since.elapsed() >= SILENCE_GRACE {
                    pick_run(&runs, run, connect)?;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
            silent_since = None;
            let target = match target {
                Some(t) => t,
                None => *target.insert(pick_run(&runs, run, connect)?),
            };
            let now = runs.iter().find(|r| r.run == target).map(|r| r.state);
            match now {
                Some(state) if state.when_done().is_none() => return anyhow::Ok(state),
                // Acting, or gone for a moment between two answers: asked again.
                _ => tokio::time::sleep(Duration::from_millis(50)).await,
            }
        }
    })
    .await;
    session.close().await.zenoh()?;
    match settled {
        Ok(state) => {
            println!("the run is {}", state?.name());
            Ok(())
        }
        Err(_) => bail!("the run did not finish what the command began within {} s (--wait)", limit.as_secs()),
    }
}

/// The status of every run behind `session`'s router, asked again for up to `SILENCE_GRACE` while none answers: a
/// run's session to its router may be dropped and made again at any moment (zenoh-link-tls drops a TLS session under
/// load and reconnects it at once: ARCHITECTURE.md, open points), and a question asked then finds nobody. Only the
/// question of who is there is asked again, never a command, which a run may have taken before its answer was lost.
async fn runs_answering(session: &Session) -> anyhow::Result<Vec<StatusReport>> {
    let since = Instant::now();
    loop {
        let runs: Vec<StatusReport> = ask(session, keys::status_any_run(), None).await?;
        if !runs.is_empty() || since.elapsed() >= SILENCE_GRACE {
            return Ok(runs);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// The status of every run behind `session`'s router.
/// The election as `baton status --json` shows it: `{"active": {name, term, since_unix_ms} | null, "standbys": […]}`.
fn election_json(candidates: &[crate::election::Candidate]) -> serde_json::Value {
    serde_json::json!({ "active": candidates.first(), "standbys": candidates.get(1..).unwrap_or_default() })
}

fn print_election(candidates: &[crate::election::Candidate]) {
    let ago = |since: u64| baton_host::unix_ms().saturating_sub(since) / 1000;
    match candidates.split_first() {
        None => println!("  coordinators: nobody stands in the election"),
        Some((active, standbys)) => {
            println!(
                "  coordinator: {} (term {}), active for {} s",
                active.name,
                active.term,
                ago(active.since_unix_ms)
            );
            for s in standbys {
                println!("    standing by: {} for {} s", s.name, ago(s.since_unix_ms));
            }
        }
    }
}

pub async fn status_on(session: &Session) -> anyhow::Result<Vec<StatusReport>> {
    ask(session, keys::status_any_run(), None).await
}

/// Sends an operator's command to run `run` (or, with `None`, to every chart behind `session`'s router, which only a
/// router of one run may do), as `request.by`: their replies.
pub async fn ctl_on(session: &Session, run: Option<RunId>, request: &CtlRequest) -> anyhow::Result<Vec<CtlReply>> {
    let by = keys::sender_name(&request.by);
    let key = run.map_or_else(|| keys::ctl_any_run(&by), |r| keys::ctl(r, &by));
    ask(session, key, Some(wire::encode(request))).await
}

/// The run `wanted` names — a run id, or a prefix of one, as `baton status` lists them — among `runs`; without
/// `wanted`, the only one there is. None, or several, is an error that lists them.
pub fn pick_run(runs: &[StatusReport], wanted: Option<&str>, connect: &[String]) -> anyhow::Result<RunId> {
    let list = |runs: &[&StatusReport]| {
        runs.iter()
            .map(|r| {
                format!(
                    "\n  run {}: chart `{}` (version {}), running for {} ms",
                    r.run.key(),
                    r.chart,
                    r.hash.0,
                    r.t_ms.saturating_sub(r.started_ms)
                )
            })
            .collect::<String>()
    };
    let all: Vec<&StatusReport> = runs.iter().collect();
    if all.is_empty() {
        bail!("no running chart answered behind {} (or the router's access control refused you)", connect.join(", "));
    }
    let matching: Vec<&StatusReport> = match wanted {
        Some(w) => {
            let w = w.trim().to_ascii_lowercase().replace('-', "");
            all.iter().copied().filter(|r| r.run.key().starts_with(&w)).collect()
        }
        None => all.clone(),
    };
    match (matching.as_slice(), wanted) {
        ([one], _) => Ok(one.run),
        ([], Some(w)) => bail!("no run `{w}` behind {}; the runs there:{}", connect.join(", "), list(&all)),
        (_, Some(w)) => bail!("`{w}` names several runs; give more of the run id:{}", list(&matching)),
        (_, None) => bail!(
            "{} runs are behind {}: say which with --run ID (nothing was set):{}",
            matching.len(),
            connect.join(", "),
            list(&matching)
        ),
    }
}

/// Sets an input of run `run` (or, with `None`, of every chart behind `session`'s router, which only a router of
/// one run may do): their replies.
pub async fn set_on(
    session: &Session,
    run: Option<RunId>,
    name: &str,
    value: serde_json::Value,
) -> anyhow::Result<Vec<SetReply>> {
    set_as(session, run, name, value, (&sender(None), None)).await
}

/// Sets input `name` of run `run` (or of every chart behind the router) as `by` (for `user`, a console's), on the
/// key that names `by`.
pub async fn set_as(
    session: &Session,
    run: Option<RunId>,
    name: &str,
    value: serde_json::Value,
    (by, user): (&str, Option<&str>),
) -> anyhow::Result<Vec<SetReply>> {
    let request =
        wire::encode(&SetRequest { name: name.to_string(), value, by: by.to_string(), user: user.map(str::to_string) });
    let key = run.map_or_else(|| keys::set_any_run(by), |r| keys::set(r, by));
    ask(session, key, Some(request)).await
}

/// The skills the agents live behind a router announce (`baton check --connect`): each agent by name, and a
/// catalogue of every skill one of them has (a built-in one with its parameters, another with its parameters left
/// open).
pub async fn live_skills(
    connect: &[String],
    file: Option<&Path>,
) -> anyhow::Result<(Vec<String>, baton_proto::cluster::skills::Catalogue)> {
    use baton_proto::cluster::skills::Catalogue;
    let session = open(connect, file).await?;
    let tokens =
        baton_host::traffic::liveliness_get(&session, keys::alive_any()).timeout(QUERY_TIMEOUT).await.zenoh()?;
    let mut agents = Vec::new();
    while let Ok(reply) = tokens.recv_async().await {
        if let Some(name) = reply.result().ok().and_then(|s| keys::agent_of_alive(s.key_expr().as_str())) {
            agents.push(name.to_string());
        }
    }
    agents.sort();
    agents.dedup();
    let mut names = Vec::new();
    for agent in &agents {
        let infos: Vec<wire::AgentInfo> = ask(&session, keys::agent_info(agent), None).await?;
        names.extend(infos.into_iter().filter(|i| i.name == *agent).flat_map(|i| i.skills.unwrap_or_default()));
    }
    let known = Catalogue::of_names(names);
    session.close().await.zenoh()?;
    Ok((agents, known))
}

/// Adds to each report's `why` what its agents say of their own steps: each agent is asked once, for every run it
/// takes part in.
pub async fn add_agents_why(session: &Session, reports: &mut [StatusReport]) -> anyhow::Result<()> {
    let mut agents: Vec<String> = reports.iter().flat_map(|r| r.agents.iter().map(|a| a.name.clone())).collect();
    agents.sort();
    agents.dedup();
    for agent in agents {
        let answers: Vec<WhyReport> = ask(session, keys::agent_why(&agent), None).await?;
        for answer in answers.into_iter().filter(|w| w.agent == agent) {
            if let Some(r) = reports.iter_mut().find(|r| r.run == answer.run) {
                r.why.extend(answer.steps);
                r.why.sort_by(|a, b| a.step.cmp(&b.step));
            }
        }
    }
    Ok(())
}

/// `coordinators`: the run's election (`--election`), the active coordinator first; shown with each chart.
pub async fn status(
    connect: &[String],
    file: Option<&Path>,
    json: bool,
    why: bool,
    coordinators: Option<Vec<crate::election::Candidate>>,
) -> anyhow::Result<()> {
    let session = open(connect, file).await?;
    let mut reports: Vec<StatusReport> = ask(&session, keys::status_any_run(), None).await?;
    if why {
        add_agents_why(&session, &mut reports).await?;
    } else {
        reports.iter_mut().for_each(|r| r.why.clear());
    }
    session.close().await.zenoh()?;
    if reports.is_empty() {
        bail!("no running chart answered behind {}", connect.join(", "));
    }
    reports.sort_by(|a, b| a.chart.cmp(&b.chart));
    if json {
        for r in &reports {
            let mut line = serde_json::to_value(r)?;
            if let (Some(c), Some(fields)) = (&coordinators, line.as_object_mut()) {
                fields.insert("coordinators".into(), election_json(c));
            }
            println!("{line}");
        }
        return Ok(());
    }
    for r in &reports {
        let running = r.t_ms.saturating_sub(r.started_ms);
        println!("chart `{}` (run {}, version {}), running for {running} ms", r.chart, r.run.key(), r.hash.0);
        if let Some(c) = &coordinators {
            print_election(c);
        }
        let legal: Vec<&str> = r.available.iter().map(|c| c.name()).collect();
        println!("  state: {} (legal commands: {})", r.state, legal.join(", "));
        if r.mode != baton_proto::exec::engine::Mode::Auto {
            let waiting = if r.waiting.is_empty() { "none".to_string() } else { r.waiting.join(", ") };
            println!("  mode: {} (waiting for confirm: {waiting})", r.mode.name());
        }
        if !r.held.is_empty() {
            println!("  held while the rest goes on: {}", r.held.join(", "));
        }
        if !r.alarms.is_empty() {
            println!("  alarms: {}", r.alarms.len());
            for a in &r.alarms {
                let state = serde_json::to_value(a.state).ok().and_then(|v| v.as_str().map(str::to_string));
                println!(
                    "    {} {} ({}, at {} ms): {}",
                    a.id,
                    a.source,
                    state.unwrap_or_default(),
                    a.raised_ms,
                    a.message
                );
            }
        }
        if !r.shelved.is_empty() {
            println!("  shelved: {}", r.shelved.len());
            for a in &r.shelved {
                let until = a.shelved_until_ms.map(|t| format!("until {t} ms")).unwrap_or_default();
                let (by, reason) = a.shelf.as_ref().map_or(("?", None), |s| (s.by.as_str(), s.reason.as_deref()));
                let reason = reason.map(|r| format!(": {r}")).unwrap_or_default();
                println!("    {} {} ({until}, by {by}{reason}): {}", a.id, a.source, a.message);
            }
        }
        if why {
            print_why(&r.why);
        }
        println!("  active steps:");
        for s in &r.active_steps {
            let at = s.agent.as_ref().map_or(String::new(), |a| format!(" on `{a}`"));
            println!("    {} ({}){at}", s.name, s.placement);
        }
        println!("  tokens in flight: {}", r.tokens.len());
        for t in &r.tokens {
            let at = t.agent.as_ref().map_or("waiting for an agent".to_string(), |a| format!("on `{a}`"));
            let paused = match (t.paused, t.held, t.held_confirmed) {
                (true, _, _) => " (paused: its agent is lost)",
                (_, true, true) => " (held: nothing of it runs)",
                (_, true, false) => " (holding: waiting for its agent to confirm)",
                _ => "",
            };
            // Where it is now; where it was dispatched, when that is another step.
            let now = if t.at.is_empty() { t.entry.clone() } else { t.at.join(", ") };
            let entered = if t.at.is_empty() || t.at == [t.entry.clone()] {
                String::new()
            } else {
                format!(" (entered at {})", t.entry)
            };
            println!("    {} epoch {} at {now}{entered} {at}, since {} ms{paused}", t.token, t.epoch, t.since_ms);
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
        if r.messages_dropped > 0 {
            println!("  messages refused: {} (see the coordinator's log for what and from whom)", r.messages_dropped);
        }
    }
    Ok(())
}
