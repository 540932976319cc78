//! Whether the router took the roles an agent announces: a role the agent's identity may not serve is refused by
//! the router's rules, and the agent says which before it serves anything. `LIVELINESS_CHECK_TIMEOUT` bounds the
//! host's check of the agent's name as well.

use std::collections::HashMap;
use std::time::Duration;

use anyhow::anyhow;
use baton_host::traffic;
use baton_proto::cluster::keys;
use zenoh::Session;

/// How long the agent waits for the router to say whether another process holds its name. The router answers at
/// once from its tables, ending the wait; the bound is for a router too busy to answer (a loaded machine took
/// more than 2 s once), and a second process under the name must not slip through it.
pub(crate) const LIVELINESS_CHECK_TIMEOUT: Duration = Duration::from_secs(10);
/// How often an agent asks the router whether it took its role tokens before a role counts as refused, and the
/// first pause between two questions (doubling): about a third of a second in all for a refusal.
const ROLE_CHECK_ATTEMPTS: u32 = 6;
const ROLE_CHECK_FIRST_PAUSE: Duration = Duration::from_millis(10);

/// The first of `roles` the router did not take the agent's token of, if any: the router's answer to a liveliness
/// query lists the tokens it has, and this session answers with its own, so each role taken is answered twice. The
/// question may overtake the token's declaration on the way (Zenoh sends them in queues of different priorities),
/// so a role answered once is asked about again, `ROLE_CHECK_ATTEMPTS` times in all, before it counts as refused.
pub(crate) async fn refused_role(session: &Session, name: &str, roles: &[String]) -> anyhow::Result<Option<String>> {
    let mut pause = ROLE_CHECK_FIRST_PAUSE;
    let mut unconfirmed: Vec<&String> = roles.iter().collect();
    for attempt in 1..=ROLE_CHECK_ATTEMPTS {
        if unconfirmed.is_empty() {
            return Ok(None);
        }
        let replies = traffic::liveliness_get(session, keys::alive_roles(name))
            .timeout(LIVELINESS_CHECK_TIMEOUT)
            .await
            .map_err(|e| anyhow!("cannot ask the router which roles it took: {e}"))?;
        let mut answers: HashMap<String, usize> = HashMap::new();
        while let Ok(reply) = replies.recv_async().await {
            if let Ok(sample) = reply.result() {
                if let Some(role) = keys::role_of_alive(sample.key_expr().as_str(), name) {
                    *answers.entry(role.to_string()).or_default() += 1;
                }
            }
        }
        unconfirmed.retain(|r| answers.get(r.as_str()).copied().unwrap_or(0) < 2);
        if attempt < ROLE_CHECK_ATTEMPTS && !unconfirmed.is_empty() {
            tokio::time::sleep(pause).await;
            pause *= 2;
        }
    }
    Ok(unconfirmed.first().map(|r| r.to_string()))
}
