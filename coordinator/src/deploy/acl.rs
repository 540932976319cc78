//! `baton deploy acl CHART`: a router's access control for a cell, from the chart's placement and the identities
//! of its processes — deny by default, and each identity allowed only what its part needs:
//!
//! - an agent declares only its own liveliness token, the tokens of the roles its deployment gives it
//!   (`baton/alive/A`, `baton/alive/A/role/R`) and its own queryables (`baton/agent/A/info|why`), asks the router
//!   only about its own tokens (the name check at its start, and the lease watch), subscribes only to its own
//!   commands (`baton/agent/A/*/cmd`) and to variable updates, publishes reports, variable updates and device
//!   reports only on its own keys (`…/report/A`, `…/vars/A`, `…/devices/A`), fetches charts, and uses the Zenoh keys
//!   its bindings in the chart name;
//! - a coordinator alone commands agents, publishes the coordinator's variables and its runs' live trace, and
//!   answers `chart`, `status`, `history`, `set` and `ctl`;
//! - each operator alone `set`s and `ctl`s on its own keys (`baton/run/*/set/O`, `…/ctl/O`), whose name the
//!   coordinator records as who asked; operators and viewers read `status`, `chart`, `history` and `why`, and
//!   hear the runs' live trace (`baton console` runs as one of them).
//!
//! What each Baton process sends is what `baton_host::traffic` lists; `tests/tests/deploying.rs` runs a cell
//! behind these rules with every process listing it, and checks each message against them.
//!
//! Rules name keys per flow: `ingress` is what a process sends into the router, `egress` what the router lets reach
//! it. Declarations of subscribers, queryables and liveliness tokens reach every Baton process (they say where
//! data may go, not the data), so that a publisher knows its subscriber is there. The subjects are certificate
//! common names (mutual TLS, `baton deploy certs`) or Zenoh user names.

use std::collections::BTreeMap;

use anyhow::bail;
use baton_proto::cluster::bindings::{IoDir, IoKind};
use baton_proto::cluster::keys::is_valid_name;
use baton_proto::cluster::layout::{Layout, Placement};
use baton_proto::cluster::netconfig::TX_QUEUE_DATA;
use baton_proto::exec::program::Program;
use serde_json::{json, Value};

/// How the router knows a process: its TLS certificate's common name, or its Zenoh user name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum By {
    Cert,
    User,
}

/// The processes of a cell, by identity.
#[derive(Clone, Debug, Default)]
pub struct Identities {
    pub coordinators: Vec<String>,
    /// Agents and the roles each serves.
    pub agents: Vec<(String, Vec<String>)>,
    pub operators: Vec<String>,
    pub viewers: Vec<String>,
    /// `baton console` processes: each sends the commands of the users logged in to it under its own name, as an
    /// operator does.
    pub consoles: Vec<String>,
}

const DECLARATIONS: [&str; 3] = ["declare_subscriber", "declare_queryable", "liveliness_token"];

/// One allowance: `messages` on `keys` in `flow`.
struct Allow {
    flow: &'static str,
    messages: &'static [&'static str],
    keys: Vec<String>,
}

fn allow(flow: &'static str, messages: &'static [&'static str], keys: &[&str]) -> Allow {
    Allow { flow, messages, keys: keys.iter().map(|k| k.to_string()).collect() }
}

/// What an agent named `a` serving `roles` may do, with the Zenoh keys its bindings publish (`outputs`) and
/// subscribe (`inputs`).
fn agent_rules(a: &str, roles: &[String], inputs: &[String], outputs: &[String]) -> Vec<Allow> {
    let own = |kind: &str| format!("baton/run/*/{kind}/{a}");
    let mut put_in = vec![own("report"), own("vars"), own("devices")];
    put_in.extend(outputs.iter().cloned());
    let mut sub = vec![format!("baton/agent/{a}/*/cmd"), "baton/run/*/vars/*".to_string()];
    sub.extend(inputs.iter().cloned());
    let queryables = [format!("baton/agent/{a}/info"), format!("baton/agent/{a}/why")];
    let mut tokens = vec![format!("baton/alive/{a}")];
    tokens.extend(roles.iter().map(|r| format!("baton/alive/{a}/role/{r}")));
    vec![
        Allow { flow: "ingress", messages: &["put"], keys: put_in },
        Allow { flow: "ingress", messages: &["declare_subscriber"], keys: sub.clone() },
        Allow { flow: "ingress", messages: &["declare_queryable", "reply"], keys: queryables.to_vec() },
        Allow { flow: "ingress", messages: &["liveliness_token"], keys: tokens },
        Allow {
            flow: "ingress",
            messages: &["liveliness_query"],
            keys: vec![format!("baton/alive/{a}"), format!("baton/alive/{a}/role/*")],
        },
        allow("ingress", &["query"], &["baton/run/*/chart"]),
        Allow { flow: "egress", messages: &["put"], keys: sub },
        Allow { flow: "egress", messages: &["query"], keys: queryables.to_vec() },
        allow("egress", &["reply"], &["baton/run/*/chart"]),
    ]
}

fn coordinator_rules() -> Vec<Allow> {
    let queryables =
        ["baton/run/*/chart", "baton/run/*/status", "baton/run/*/set/*", "baton/run/*/ctl/*", "baton/run/*/history"];
    let from_agents = ["baton/run/*/report/*", "baton/run/*/vars/*", "baton/run/*/devices/*"];
    vec![
        allow("ingress", &["put"], &["baton/agent/*/*/cmd", "baton/run/*/vars/coordinator", "baton/run/*/trace"]),
        allow("ingress", &["declare_subscriber"], &from_agents),
        allow("ingress", &["declare_liveliness_subscriber"], &["baton/alive/*"]),
        allow("ingress", &["liveliness_query"], &["baton/alive/*", "baton/alive/*/role/*"]),
        allow("ingress", &["query"], &["baton/agent/*/info"]),
        allow("ingress", &["declare_queryable", "reply"], &queryables),
        allow("egress", &["put"], &from_agents),
        allow("egress", &["liveliness_token"], &["baton/alive/*"]),
        allow("egress", &["reply"], &["baton/agent/*/info"]),
        allow("egress", &["query"], &queryables),
    ]
}

/// What a viewer may ask, and hear: a run's status, chart and history, an agent's why, and a run's live trace (what
/// `baton console` follows); an operator `o` may also `set` and `ctl`, on the keys that name it.
fn operator_rules(o: Option<&str>) -> Vec<Allow> {
    let mut asks: Vec<String> = ["baton/run/*/status", "baton/run/*/chart", "baton/run/*/history", "baton/agent/*/why"]
        .map(str::to_string)
        .to_vec();
    if let Some(o) = o {
        asks.extend([format!("baton/run/*/set/{o}"), format!("baton/run/*/ctl/{o}")]);
    }
    vec![
        Allow { flow: "ingress", messages: &["query"], keys: asks.clone() },
        Allow { flow: "egress", messages: &["reply"], keys: asks },
        allow("ingress", &["declare_subscriber"], &["baton/run/*/trace"]),
        allow("egress", &["put"], &["baton/run/*/trace"]),
    ]
}

/// The `access_control` section of a router's configuration for `program` placed by `layout`.
pub fn access_control(program: &Program, layout: &Layout, ids: &Identities, by: By) -> anyhow::Result<Value> {
    check(program, layout, ids)?;
    let mut rules = Vec::new();
    let mut subjects = Vec::new();
    let mut policies = Vec::new();
    let mut add = |id: String, names: &[String], allows: Vec<Allow>| {
        let mut ids = Vec::new();
        for (k, a) in allows.into_iter().enumerate() {
            let rule = format!("{id}-{}-{k}", a.flow);
            rules.push(json!({
                "id": rule, "permission": "allow", "flows": [a.flow], "messages": a.messages, "key_exprs": a.keys,
            }));
            ids.push(rule);
        }
        let names_key = match by {
            By::Cert => "cert_common_names",
            By::User => "usernames",
        };
        subjects.push(json!({ "id": id, names_key: names }));
        policies.push(json!({ "rules": ids, "subjects": [id] }));
    };
    // Everyone of the cell learns where subscribers, queryables and liveliness tokens are.
    let everyone: Vec<String> = ids
        .coordinators
        .iter()
        .chain(ids.agents.iter().map(|(n, _)| n))
        .chain(&ids.operators)
        .chain(&ids.viewers)
        .chain(&ids.consoles)
        .cloned()
        .collect();
    add(
        "cell".to_string(),
        &everyone,
        vec![Allow { flow: "egress", messages: &DECLARATIONS, keys: keys_everywhere(layout) }],
    );
    if !ids.coordinators.is_empty() {
        add("coordinators".to_string(), &ids.coordinators, coordinator_rules());
    }
    for (name, roles) in &ids.agents {
        let bound = |dir: IoDir| -> Vec<String> {
            let mut keys: Vec<String> = layout
                .io
                .iter()
                .filter(|b| &b.agent == name && b.dir == dir && b.kind == IoKind::Zenoh)
                .filter_map(|b| b.key().map(str::to_string))
                .collect();
            keys.sort();
            keys.dedup();
            keys
        };
        add(
            format!("agent-{name}"),
            std::slice::from_ref(name),
            agent_rules(name, roles, &bound(IoDir::Input), &bound(IoDir::Output)),
        );
    }
    // An operator's `set` and `ctl` keys name it: a policy of its own each.
    for o in &ids.operators {
        add(format!("operator-{o}"), std::slice::from_ref(o), operator_rules(Some(o)));
    }
    // A console asks as an operator does, on its own keys; which of its users may do what is the console's.
    for c in &ids.consoles {
        add(format!("console-{c}"), std::slice::from_ref(c), operator_rules(Some(c)));
    }
    if !ids.viewers.is_empty() {
        add("viewers".to_string(), &ids.viewers, operator_rules(None));
    }
    Ok(json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }))
}

/// Baton's keys, and the chart's bound Zenoh keys: where declarations may reach every process of the cell.
fn keys_everywhere(layout: &Layout) -> Vec<String> {
    let mut keys = vec!["baton/**".to_string()];
    keys.extend(layout.io.iter().filter(|b| b.kind == IoKind::Zenoh).filter_map(|b| b.key().map(str::to_string)));
    keys.sort();
    keys.dedup();
    keys
}

/// Every identity is a name Baton takes, none twice; every agent the chart places a step on by name is given, and
/// every role has an agent.
fn check(program: &Program, layout: &Layout, ids: &Identities) -> anyhow::Result<()> {
    let mut seen: BTreeMap<&str, &str> = BTreeMap::new();
    let all = ids
        .coordinators
        .iter()
        .map(|n| (n, "coordinator"))
        .chain(ids.agents.iter().map(|(n, _)| (n, "agent")))
        .chain(ids.operators.iter().map(|n| (n, "operator")))
        .chain(ids.viewers.iter().map(|n| (n, "viewer")))
        .chain(ids.consoles.iter().map(|n| (n, "console")));
    for (name, what) in all {
        if !is_valid_name(name) {
            bail!("`{name}` is not a name Baton takes: letters, digits, `_` and `-`, at most 64");
        }
        if let Some(before) = seen.insert(name, what) {
            bail!("`{name}` is both {before} and {what}: one identity, one part (give each process its own)");
        }
    }
    for (name, roles) in &ids.agents {
        if let Some(bad) = roles.iter().find(|r| !is_valid_name(r)) {
            bail!("agent `{name}`'s role `{bad}` is not a name Baton takes: letters, digits, `_` and `-`, at most 64");
        }
    }
    if ids.coordinators.is_empty() && ids.agents.is_empty() {
        bail!("name the cell's processes: --coordinator NAME and --agent NAME[=ROLE,…]");
    }
    let agents: BTreeMap<&str, &Vec<String>> = ids.agents.iter().map(|(n, r)| (n.as_str(), r)).collect();
    let steps_of = |p: &Placement| -> Vec<&str> {
        layout
            .segments
            .iter()
            .filter(|s| &s.placement == p)
            .flat_map(|s| s.steps.iter().map(|st| program.steps[st.index()].name.as_str()))
            .collect()
    };
    for seg in &layout.segments {
        match &seg.placement {
            Placement::Agent(a) if !agents.contains_key(a.as_str()) => {
                bail!(
                    "chart `{}` places step `{}` on agent `{a}`: give its identity with --agent {a}",
                    program.name,
                    steps_of(&seg.placement).first().unwrap_or(&"?")
                );
            }
            Placement::Role(r) if !agents.values().any(|roles| roles.contains(r)) => {
                bail!(
                    "chart `{}` places step `{}` on role `{r}`: give an agent of that role with --agent NAME={r}",
                    program.name,
                    steps_of(&seg.placement).first().unwrap_or(&"?")
                );
            }
            _ => {}
        }
    }
    for b in &layout.io {
        if !agents.contains_key(b.agent.as_str()) {
            bail!(
                "chart `{}` binds `{}` on agent `{}`: give its identity with --agent {}",
                program.name,
                b.name,
                b.agent,
                b.agent
            );
        }
    }
    Ok(())
}

/// A router's whole configuration: `listen` endpoints, mutual TLS with `tls` = (CA, certificate, key) files when
/// given, and `acl`.
pub fn router_config(acl: Value, listen: &[String], tls: Option<(String, String, String)>) -> Value {
    let mut config = json!({
        "mode": "router",
        "listen": { "endpoints": listen },
        "scouting": { "multicast": { "enabled": false } },
        "access_control": acl,
        // The router forwards every message; its links get the batches Baton's own processes ask for.
        "transport": { "link": { "tx": { "queue": { "size": { "data": TX_QUEUE_DATA } } } } },
    });
    if let Some((ca, cert, key)) = tls {
        config["transport"]["link"]["tls"] = json!({
            "root_ca_certificate": ca,
            "listen_certificate": cert,
            "listen_private_key": key,
            "enable_mtls": true,
        });
    }
    config
}

#[cfg(test)]
mod tests {
    use super::*;

    const CHART: &str = "PROGRAM cell\nVAR door : BOOL; {input := 'zenoh', agent := 'cell1', key := 'cell1/door'}\n\
        lamp : BOOL; {output := 'zenoh', agent := 'cell1', key := 'cell1/lamp'}\nEND_VAR\n\
        INITIAL_STEP A: END_STEP\nTRANSITION FROM A TO B := door; END_TRANSITION\n\
        STEP B: {agent := 'robot1'} END_STEP\nTRANSITION FROM B TO C := TRUE; END_TRANSITION\n\
        STEP C: {role := 'welder'} END_STEP\nEND_PROGRAM\n";

    fn ids() -> Identities {
        Identities {
            coordinators: vec!["coordinator".into()],
            agents: vec![("robot1".into(), vec![]), ("cell1".into(), vec![]), ("w1".into(), vec!["welder".into()])],
            operators: vec!["anna".into()],
            viewers: vec!["screen".into()],
            consoles: vec!["console".into()],
        }
    }

    fn rules_of<'a>(acl: &'a Value, subject: &str) -> Vec<&'a Value> {
        let policy = acl["policies"].as_array().expect("policies").iter().find(|p| p["subjects"][0] == subject);
        let names: Vec<&Value> =
            policy.expect("a policy").get("rules").and_then(Value::as_array).expect("rules").iter().collect();
        acl["rules"].as_array().expect("rules").iter().filter(|r| names.contains(&&r["id"])).collect()
    }

    fn allowed(acl: &Value, subject: &str, flow: &str, message: &str) -> Vec<String> {
        rules_of(acl, subject)
            .into_iter()
            .filter(|r| {
                r["flows"][0] == flow && r["messages"].as_array().is_some_and(|m| m.iter().any(|x| x == message))
            })
            .flat_map(|r| r["key_exprs"].as_array().expect("keys").iter().map(|k| k.as_str().expect("key").to_string()))
            .collect()
    }

    /// What Zenoh itself reads: the router configuration parses, and each identity may publish only its own keys.
    #[test]
    fn each_identity_is_allowed_its_part_and_zenoh_takes_the_rules() {
        let (program, layout) = baton_proto::testing::simulated_cluster::compile(CHART);
        let acl = access_control(&program, &layout, &ids(), By::Cert).expect("rules");
        let config = router_config(acl.clone(), &["tls/127.0.0.1:7447".into()], None);
        let read = zenoh::Config::from_json5(&config.to_string()).expect("zenoh reads the configuration");
        // The router's links get the batches Baton's processes ask for, with TLS or without.
        let queue = "transport/link/tx/queue/size/data";
        assert_eq!(read.get_json(queue).expect("the queue's size"), TX_QUEUE_DATA.to_string());
        let files = ("ca.pem".to_string(), "router.pem".to_string(), "router.key".to_string());
        let tls = router_config(acl.clone(), &["tls/127.0.0.1:7447".into()], Some(files));
        let read = zenoh::Config::from_json5(&tls.to_string()).expect("zenoh reads the TLS configuration");
        assert_eq!(read.get_json(queue).expect("the queue's size"), TX_QUEUE_DATA.to_string());
        assert_eq!(read.get_json("transport/link/tls/enable_mtls").expect("mTLS"), "true");
        assert_eq!(acl["default_permission"], "deny");
        let puts = allowed(&acl, "agent-cell1", "ingress", "put");
        assert_eq!(
            puts,
            ["baton/run/*/report/cell1", "baton/run/*/vars/cell1", "baton/run/*/devices/cell1", "cell1/lamp"]
        );
        assert!(allowed(&acl, "agent-cell1", "ingress", "declare_subscriber").contains(&"cell1/door".to_string()));
        assert_eq!(allowed(&acl, "agent-robot1", "ingress", "liveliness_token"), ["baton/alive/robot1"]);
        // w1 may announce the role its deployment gives it, and no other.
        assert_eq!(
            allowed(&acl, "agent-w1", "ingress", "liveliness_token"),
            ["baton/alive/w1", "baton/alive/w1/role/welder"]
        );
        assert_eq!(
            allowed(&acl, "agent-robot1", "ingress", "liveliness_query"),
            ["baton/alive/robot1", "baton/alive/robot1/role/*"]
        );
        assert!(allowed(&acl, "agent-robot1", "ingress", "query").iter().all(|k| k == "baton/run/*/chart"));
        let coordinator_puts = allowed(&acl, "coordinators", "ingress", "put");
        assert_eq!(coordinator_puts, ["baton/agent/*/*/cmd", "baton/run/*/vars/coordinator", "baton/run/*/trace"]);
        // A console, viewer or operator, hears the runs' live trace and publishes nothing.
        assert_eq!(allowed(&acl, "viewers", "ingress", "declare_subscriber"), ["baton/run/*/trace"]);
        assert!(allowed(&acl, "viewers", "ingress", "put").is_empty());
        assert!(allowed(&acl, "operator-anna", "ingress", "put").is_empty());
        // A console operates on the keys that name it, as an operator does.
        let console = allowed(&acl, "console-console", "ingress", "query");
        assert!(console.contains(&"baton/run/*/ctl/console".to_string()), "{console:?}");
        assert!(!console.iter().any(|k| k.ends_with("/ctl/*") || k.ends_with("/ctl/anna")), "{console:?}");
        // An operator asks only on the keys that name it.
        let asks = allowed(&acl, "operator-anna", "ingress", "query");
        assert!(
            asks.contains(&"baton/run/*/ctl/anna".to_string()) && asks.contains(&"baton/run/*/set/anna".to_string())
        );
        assert!(!asks.iter().any(|k| k.ends_with("/*") && (k.contains("/ctl/") || k.contains("/set/"))), "{asks:?}");
        assert!(!allowed(&acl, "viewers", "ingress", "query").iter().any(|k| k.contains("/ctl") || k.contains("/set")));
        let subjects = acl["subjects"].as_array().expect("subjects");
        assert!(subjects.iter().all(|s| s.get("cert_common_names").is_some()));
        let by_user = access_control(&program, &layout, &ids(), By::User).expect("rules");
        assert!(by_user["subjects"].as_array().expect("subjects").iter().all(|s| s.get("usernames").is_some()));
    }

    #[test]
    fn a_cell_whose_identities_do_not_cover_the_chart_is_refused() {
        let (program, layout) = baton_proto::testing::simulated_cluster::compile(CHART);
        let refused =
            |ids: Identities| access_control(&program, &layout, &ids, By::Cert).expect_err("refused").to_string();
        let mut no_robot = ids();
        no_robot.agents.retain(|(n, _)| n != "robot1");
        assert!(refused(no_robot).contains("places step `B` on agent `robot1`: give its identity with --agent robot1"));
        let mut no_welder = ids();
        no_welder.agents.retain(|(n, _)| n != "w1");
        assert!(refused(no_welder).contains("places step `C` on role `welder`"));
        let mut no_cell = ids();
        no_cell.agents.retain(|(n, _)| n != "cell1");
        assert!(refused(no_cell).contains("binds `door` on agent `cell1`"));
        let mut twice = ids();
        twice.operators.push("robot1".into());
        assert!(refused(twice).contains("`robot1` is both agent and operator"));
        let mut bad = ids();
        bad.viewers.push("wall screen".into());
        assert!(refused(bad).contains("is not a name Baton takes"));
    }

    /// The router configurations the repository ships, as Zenoh reads them: each gives its links the batches
    /// Baton's own processes ask for, so that the router in the middle does not bring back the wait they remove.
    #[test]
    fn the_shipped_router_configurations_give_links_baton_s_queue() {
        let deploy = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy");
        for file in ["zenohd.json5", "acl/zenohd.json5", "tls/router.json5"] {
            let read = zenoh::Config::from_file(deploy.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
            let queue = read.get_json("transport/link/tx/queue/size/data").expect("the queue's size");
            assert_eq!(queue, TX_QUEUE_DATA.to_string(), "{file}");
        }
    }
}
