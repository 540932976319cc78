//! The cable between one agent and the router in `baton test --cluster`: a loopback TCP relay the runner can
//! pull out (`cut`), plug back in (`heal`) and slow down (`delay`).
//!
//! A cut does what a pulled cable does to TCP: nothing passes either way, no connection is closed, and what was
//! sent waits (the relay stops reading, so the kernel's buffers fill and the sender's TCP holds the rest). Both
//! ends notice only by their own leases — Baton's and Zenoh's. Plugged back in, what waited flows on; an end
//! that gave up meanwhile closes its side, the relay closes the other, and the agent connects again. A delay
//! holds each chunk for up to `delay` ms, in order (TCP cannot lose, duplicate or reorder what it carries: those
//! faults need the simulated network).

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use baton_proto::testing::simulated_cluster::Rng;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio::time::Instant;

#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct State {
    cut: bool,
    /// Largest extra delay of a chunk, in ms.
    delay_ms: u64,
}

pub struct Cable {
    port: u16,
    state: Arc<watch::Sender<State>>,
    accept: JoinHandle<()>,
}

impl Cable {
    /// A relay on a free loopback port to `router`; `seed` draws the delays.
    pub async fn lay(router: SocketAddr, seed: u64) -> std::io::Result<Cable> {
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        let port = listener.local_addr()?.port();
        let state = Arc::new(watch::Sender::new(State::default()));
        let shared = Arc::clone(&state);
        let accept = tokio::spawn(async move {
            let mut k = 0u64;
            while let Ok((agent_side, _)) = listener.accept().await {
                k += 1;
                let state = Arc::clone(&shared);
                tokio::spawn(relay(agent_side, router, state, seed.wrapping_add(k)));
            }
        });
        Ok(Cable { port, state, accept })
    }

    /// Where the agent connects.
    pub fn endpoint(&self) -> String {
        format!("tcp/127.0.0.1:{}", self.port)
    }

    pub fn cut(&self) {
        self.state.send_modify(|s| s.cut = true);
    }

    pub fn heal(&self) {
        self.state.send_modify(|s| s.cut = false);
    }

    pub fn delay(&self, ms: u64) {
        self.state.send_modify(|s| s.delay_ms = ms);
    }
}

impl Drop for Cable {
    fn drop(&mut self) {
        self.accept.abort();
    }
}

/// Waits while the cable is cut.
async fn plugged(state: &mut watch::Receiver<State>) -> Option<State> {
    state.wait_for(|s| !s.cut).await.ok().map(|s| *s)
}

/// One connection: to the router once the cable is plugged in, then both directions until either end closes.
async fn relay(agent_side: TcpStream, router: SocketAddr, state: Arc<watch::Sender<State>>, seed: u64) {
    let mut rx = state.subscribe();
    if plugged(&mut rx).await.is_none() {
        return;
    }
    let Ok(router_side) = TcpStream::connect(router).await else { return };
    let _ = agent_side.set_nodelay(true);
    let _ = router_side.set_nodelay(true);
    let (ar, aw) = agent_side.into_split();
    let (rr, rw) = router_side.into_split();
    let up = pump(ar, rw, state.subscribe(), Rng::new(seed, 1));
    let down = pump(rr, aw, state.subscribe(), Rng::new(seed, 2));
    // When one direction ends (an end closed), the other is dropped too: both sockets close.
    tokio::select! {
        () = up => {}
        () = down => {}
    }
}

async fn pump(
    mut from: tokio::net::tcp::OwnedReadHalf,
    mut to: tokio::net::tcp::OwnedWriteHalf,
    mut state: watch::Receiver<State>,
    mut rng: Rng,
) {
    let mut buf = vec![0u8; 64 * 1024];
    // Chunks leave in order: none before the one ahead of it.
    let mut last_out = Instant::now();
    loop {
        let Some(before) = plugged(&mut state).await else { return };
        let n = match from.read(&mut buf).await {
            Ok(0) | Err(_) => {
                let _ = to.shutdown().await;
                return;
            }
            Ok(n) => n,
        };
        // Read while plugged in, but the cable may have been pulled since: then it waits.
        let Some(after) = plugged(&mut state).await else { return };
        let delay_ms = before.delay_ms.max(after.delay_ms);
        if delay_ms > 0 {
            let at = (Instant::now() + Duration::from_millis(rng.next_u64() % (delay_ms + 1))).max(last_out);
            tokio::time::sleep_until(at).await;
            last_out = at;
        }
        if to.write_all(&buf[..n]).await.is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    async fn echo_server() -> SocketAddr {
        let l = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = l.local_addr().expect("addr");
        tokio::spawn(async move {
            while let Ok((mut s, _)) = l.accept().await {
                tokio::spawn(async move {
                    let mut b = [0u8; 1024];
                    while let Ok(n) = s.read(&mut b).await {
                        if n == 0 || s.write_all(&b[..n]).await.is_err() {
                            return;
                        }
                    }
                });
            }
        });
        addr
    }

    async fn roundtrip(s: &mut TcpStream, msg: &[u8]) -> Vec<u8> {
        s.write_all(msg).await.expect("write");
        let mut got = vec![0u8; msg.len()];
        s.read_exact(&mut got).await.expect("read");
        got
    }

    #[tokio::test]
    async fn a_cut_holds_everything_until_it_heals_and_closes_nothing() {
        let cable = Cable::lay(echo_server().await, 7).await.expect("lay");
        let mut s = TcpStream::connect(("127.0.0.1", cable.port)).await.expect("connect");
        assert_eq!(roundtrip(&mut s, b"before").await, b"before");
        cable.cut();
        s.write_all(b"during").await.expect("a cut does not refuse what is sent");
        let mut got = [0u8; 6];
        let early = tokio::time::timeout(Duration::from_millis(200), s.read_exact(&mut got)).await;
        assert!(early.is_err(), "nothing passes a cut cable");
        cable.heal();
        s.read_exact(&mut got).await.expect("what waited arrives");
        assert_eq!(&got, b"during");
        assert_eq!(roundtrip(&mut s, b"after").await, b"after");
    }

    #[tokio::test]
    async fn a_connection_made_during_a_cut_reaches_the_router_once_healed() {
        let cable = Cable::lay(echo_server().await, 7).await.expect("lay");
        cable.cut();
        let mut s = TcpStream::connect(("127.0.0.1", cable.port)).await.expect("connect");
        s.write_all(b"hello").await.expect("write");
        cable.heal();
        let mut got = [0u8; 5];
        s.read_exact(&mut got).await.expect("read");
        assert_eq!(&got, b"hello");
    }

    #[tokio::test]
    async fn a_delayed_cable_keeps_the_order_of_what_it_carries() {
        let cable = Cable::lay(echo_server().await, 7).await.expect("lay");
        cable.delay(20);
        let mut s = TcpStream::connect(("127.0.0.1", cable.port)).await.expect("connect");
        let mut sent = Vec::new();
        for i in 0..50u8 {
            s.write_all(&[i]).await.expect("write");
            sent.push(i);
        }
        let mut got = vec![0u8; sent.len()];
        s.read_exact(&mut got).await.expect("read");
        assert_eq!(got, sent);
    }
}
