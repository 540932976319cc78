//! A router's access control, read from its configuration as Zenoh reads it, and what a cell's processes sent
//! (`baton_host::traffic`'s lists), checked against it: each message must be let in from its sender (ingress) and
//! out to every process it reaches (egress) — a put to each subscriber whose key it meets, a query to each
//! queryable and its reply back, a token to each liveliness subscriber or query, and the declarations a sender
//! needs to know where its messages go. A message is allowed when an allow rule of its subject's policies, for its
//! flow and kind, has a key expression that includes its key (the default is deny), as zenoh 1.10's
//! `PolicyEnforcer` decides it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use baton_host::traffic::Message;
use zenoh::key_expr::KeyExpr;

/// One allow rule: its flows, the messages it names, its key expressions.
struct Rule {
    flows: Vec<String>,
    messages: Vec<String>,
    keys: Vec<KeyExpr<'static>>,
}

/// The allow rules that apply to each identity (certificate common name or user name).
pub struct Rules {
    by_identity: BTreeMap<String, Vec<Rule>>,
}

fn strings(v: &serde_json::Value) -> Vec<String> {
    v.as_array().into_iter().flatten().filter_map(|s| s.as_str().map(str::to_string)).collect()
}

impl Rules {
    /// The rules of a router configuration file (JSON5 as `baton deploy acl` writes it: JSON after a comment line).
    pub fn read(path: &Path) -> Rules {
        let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let json: String = text.lines().filter(|l| !l.trim_start().starts_with("//")).collect::<Vec<_>>().join("\n");
        let config: serde_json::Value = serde_json::from_str(&json).expect("the router's configuration");
        let acl = &config["access_control"];
        assert_eq!(acl["enabled"], true, "the access control is on");
        assert_eq!(acl["default_permission"], "deny", "it denies by default");
        let mut rules: BTreeMap<String, serde_json::Value> = BTreeMap::new();
        for r in acl["rules"].as_array().expect("rules") {
            assert_eq!(r["permission"], "allow", "the generated rules only allow: {r}");
            rules.insert(r["id"].as_str().expect("a rule id").to_string(), r.clone());
        }
        let mut names: BTreeMap<String, Vec<String>> = BTreeMap::new();
        for s in acl["subjects"].as_array().expect("subjects") {
            let mut n = strings(&s["cert_common_names"]);
            n.extend(strings(&s["usernames"]));
            names.insert(s["id"].as_str().expect("a subject id").to_string(), n);
        }
        let mut by_identity: BTreeMap<String, Vec<Rule>> = BTreeMap::new();
        for p in acl["policies"].as_array().expect("policies") {
            for subject in strings(&p["subjects"]) {
                for identity in names.get(&subject).into_iter().flatten() {
                    for id in strings(&p["rules"]) {
                        let r = &rules[&id];
                        let keys = strings(&r["key_exprs"])
                            .into_iter()
                            .map(|k| KeyExpr::try_from(k).expect("a rule's key expression"))
                            .collect();
                        let rule = Rule { flows: strings(&r["flows"]), messages: strings(&r["messages"]), keys };
                        by_identity.entry(identity.clone()).or_default().push(rule);
                    }
                }
            }
        }
        Rules { by_identity }
    }

    /// Whether `identity` may have `message` on `key` in `flow` (`ingress`: it sends it; `egress`: it receives it).
    pub fn allows(&self, identity: &str, flow: &str, message: Message, key: &str) -> bool {
        let Ok(key) = KeyExpr::try_from(key) else { return false };
        self.by_identity.get(identity).into_iter().flatten().any(|r| {
            r.flows.iter().any(|f| f == flow)
                && r.messages.iter().any(|m| m == message.name())
                && r.keys.iter().any(|k| k.includes(&key))
        })
    }
}

/// What each process of a cell sent, by identity: `baton_host::traffic`'s lists, one file per process,
/// `IDENTITY.traffic` (several processes of one identity, such as an operator's commands, share one).
pub fn read_traffic(dir: &Path) -> BTreeMap<String, BTreeSet<(Message, String)>> {
    let mut out: BTreeMap<String, BTreeSet<(Message, String)>> = BTreeMap::new();
    for entry in std::fs::read_dir(dir).expect("the traffic folder") {
        let path = entry.expect("an entry").path();
        if path.extension().is_none_or(|e| e != "traffic") {
            continue;
        }
        let identity = path.file_stem().and_then(|s| s.to_str()).expect("a name").to_string();
        let text = std::fs::read_to_string(&path).expect("a traffic list");
        let sent = out.entry(identity).or_default();
        for line in text.lines() {
            let (what, key) = line.split_once(' ').unwrap_or_else(|| panic!("{}: `{line}`", path.display()));
            let message = Message::from_name(what).unwrap_or_else(|| panic!("{}: `{what}`", path.display()));
            sent.insert((message, key.to_string()));
        }
    }
    out
}

fn intersects(a: &str, b: &str) -> bool {
    match (KeyExpr::try_from(a), KeyExpr::try_from(b)) {
        (Ok(a), Ok(b)) => a.intersects(&b),
        _ => false,
    }
}

/// Every message of `traffic` that `rules` do not let through, each saying who, which way and why it is needed; an
/// empty list when the rules carry the whole cell.
pub fn unmet(rules: &Rules, traffic: &BTreeMap<String, BTreeSet<(Message, String)>>) -> Vec<String> {
    let mut out = BTreeSet::new();
    let mut need = |who: &str, flow: &str, m: Message, key: &str, why: String| {
        if !rules.allows(who, flow, m, key) {
            out.insert(format!("{who} {flow} {} {key}  ({why})", m.name()));
        }
    };
    let kinds = |who: &str, m: Message| -> Vec<String> {
        traffic[who].iter().filter(|(k, _)| *k == m).map(|(_, key)| key.clone()).collect()
    };
    for (p, sent) in traffic {
        for (m, key) in sent {
            need(p, "ingress", *m, key, "what it sends".into());
        }
        for q in traffic.keys().filter(|q| *q != p) {
            use Message::*;
            for put in kinds(p, Put) {
                for sub in kinds(q, DeclareSubscriber).into_iter().filter(|s| intersects(s, &put)) {
                    need(q, "egress", Put, &put, format!("{p}'s put reaches its subscriber {sub}"));
                    need(p, "egress", DeclareSubscriber, &sub, format!("{p} puts on {put}, which {q} subscribes"));
                }
            }
            for query in kinds(p, Query) {
                for queryable in kinds(q, DeclareQueryable).into_iter().filter(|z| intersects(z, &query)) {
                    need(q, "egress", Query, &query, format!("{p}'s query reaches its queryable {queryable}"));
                    need(p, "egress", DeclareQueryable, &queryable, format!("{p} asks {query}, which {q} answers"));
                    for reply in kinds(q, Reply).into_iter().filter(|r| intersects(r, &query)) {
                        need(p, "egress", Reply, &reply, format!("{q}'s answer to its query {query}"));
                    }
                }
            }
            for token in kinds(p, LivelinessToken) {
                let watching = kinds(q, DeclareLivelinessSubscriber).into_iter().chain(kinds(q, LivelinessQuery));
                for watch in watching.filter(|w| intersects(w, &token)) {
                    need(q, "egress", LivelinessToken, &token, format!("{p}'s token, which it watches on {watch}"));
                }
            }
        }
        // The router itself answers a liveliness query with the tokens it has, the asker's own among them.
        for query in kinds(p, Message::LivelinessQuery) {
            for token in kinds(p, Message::LivelinessToken).into_iter().filter(|t| intersects(t, &query)) {
                need(
                    p,
                    "egress",
                    Message::LivelinessToken,
                    &token,
                    format!("the router's answer to its query {query}"),
                );
            }
        }
    }
    out.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An agent that puts its report, a coordinator subscribed to reports that commands it back: one rule missing
    /// each way is named, with why it is needed.
    #[test]
    fn a_message_without_its_rule_is_named() {
        let dir = tempfile::tempdir().expect("tmp");
        let config = serde_json::json!({ "access_control": {
            "enabled": true, "default_permission": "deny",
            "rules": [
                { "id": "a-in", "permission": "allow", "flows": ["ingress"], "messages": ["put"],
                  "key_exprs": ["baton/run/*/report/r1"] },
                { "id": "c-in", "permission": "allow", "flows": ["ingress"], "messages": ["declare_subscriber"],
                  "key_exprs": ["baton/run/*/report/*"] },
                { "id": "c-out", "permission": "allow", "flows": ["egress"], "messages": ["put"],
                  "key_exprs": ["baton/run/*/report/*"] },
            ],
            "subjects": [{ "id": "r1", "cert_common_names": ["r1"] }, { "id": "c", "cert_common_names": ["c"] }],
            "policies": [{ "rules": ["a-in"], "subjects": ["r1"] }, { "rules": ["c-in", "c-out"], "subjects": ["c"] }],
        }});
        let path = dir.path().join("router.json5");
        std::fs::write(&path, format!("// a router\n{config}")).expect("write");
        let rules = Rules::read(&path);
        let mut traffic: BTreeMap<String, BTreeSet<(Message, String)>> = BTreeMap::new();
        traffic.entry("r1".into()).or_default().insert((Message::Put, "baton/run/x/report/r1".into()));
        traffic.entry("c".into()).or_default().insert((Message::DeclareSubscriber, "baton/run/x/report/*".into()));
        // r1 must learn of the coordinator's subscriber to know its put goes somewhere.
        assert_eq!(
            unmet(&rules, &traffic),
            ["r1 egress declare_subscriber baton/run/x/report/*  (r1 puts on baton/run/x/report/r1, which c subscribes)"]
        );
        traffic.entry("r1".into()).or_default().insert((Message::Put, "baton/run/x/report/r2".into()));
        let missing = unmet(&rules, &traffic);
        assert!(missing.contains(&"r1 ingress put baton/run/x/report/r2  (what it sends)".to_string()), "{missing:?}");
    }
}
