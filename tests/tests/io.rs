//! Chart variables bound to Zenoh keys (`cluster::bindings`), through a real agent: a plain Zenoh publisher of the
//! test's own drives the chart's transitions, and the chart's outputs reach the test's subscribers.

use std::time::Duration;

use baton_proto::exec::trace::TraceEvent;
use baton_tests::loopback::{repo, Cluster, TIMEOUT};
use zenoh::pubsub::Publisher;
use zenoh::Session;

/// The next sample on `sub`, as text.
async fn next(sub: &zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>) -> String {
    let sample = tokio::time::timeout(TIMEOUT, sub.recv_async()).await.expect("a sample in time").expect("a sample");
    String::from_utf8_lossy(&sample.payload().to_bytes()).into_owned()
}

/// A publisher on `key` once the agent subscribes to it, so that nothing put is lost.
async fn publisher(session: &Session, key: &str) -> Publisher<'static> {
    let publisher = session.declare_publisher(key.to_string()).await.expect("publisher");
    let listener = publisher.matching_listener().await.expect("matching listener");
    if !publisher.matching_status().await.expect("matching status").matching() {
        let status = tokio::time::timeout(TIMEOUT, listener.recv_async()).await.expect("the agent subscribes in time");
        assert!(status.expect("matching status").matching());
    }
    publisher
}

#[tokio::test(flavor = "multi_thread")]
async fn a_zenoh_publisher_drives_a_transition_and_outputs_reach_a_subscriber() {
    let mut cluster = Cluster::with_router().await;
    let watch = cluster.watch().await;
    let lamp = watch.declare_subscriber("cell1/lamp").await.expect("subscribe");
    let shown = watch.declare_subscriber("cell1/shown").await.expect("subscribe");
    cluster.agent("cell1", &[], &[]);
    let coordinator = cluster.coordinator_joining(&repo("tests/charts/zenoh_io.st"), &[]);
    // The agent joins the run before any token comes, and sends its outputs' first values.
    assert_eq!(next(&lamp).await, "false");
    assert_eq!(next(&shown).await, "0");
    let speed = publisher(&watch, "cell1/speed").await;
    let door = publisher(&watch, "cell1/door").await;
    speed.put("1.5").await.expect("put");
    // A sample that is not a BOOL is refused, and the door stays shut.
    door.put("ajar").await.expect("put");
    cluster
        .wait_for_agent_trace("cell1", "`ajar` refused", |r| r.event == TraceEvent::InputRefused && r.name == "door")
        .await;
    door.put("true").await.expect("put");
    assert_eq!(next(&lamp).await, "true");
    assert_eq!(next(&shown).await, "3");
    // A subscriber that comes now, after the change, still hears `ready`: it is put again every 50 ms.
    let ready = watch.declare_subscriber("cell1/ready").await.expect("subscribe");
    assert_eq!((next(&ready).await, next(&ready).await), ("true".to_string(), "true".to_string()));
    door.put("false").await.expect("put");
    let (status, log, trace, summary) =
        tokio::time::timeout(TIMEOUT + Duration::from_secs(5), coordinator.finish()).await.expect("the chart ends");
    assert!(status.success(), "{log}");
    let activated: Vec<String> =
        trace.iter().filter(|r| r.event == TraceEvent::Activate).map(|r| r.name.clone()).collect();
    assert_eq!(activated, ["Wait", "Lit", "Done"]);
    assert_eq!(summary["vars"]["door"].as_str(), Some("FALSE"));
    assert_eq!(summary["vars"]["speed"].as_str(), Some("1.5"));
    assert_eq!(summary["vars"]["lamp"].as_str(), Some("TRUE"));
}
