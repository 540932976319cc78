//! A network namespace joined to the test's own by a veth pair, for partitions that a real network makes: the
//! test owns it and deletes it (and the pair with it) when dropped. Making one needs root and iproute2; where
//! that fails, `Netns::new` says why, so that a test can say clearly that it skips.
//!
//! Addresses come from 198.18.0.0/15 (reserved for network benchmarks, RFC 2544), one /30 per namespace, on the
//! veth pair only. TEST-NET-1 (192.0.2.0/24) would be the natural choice, but some machines — this project's CI
//! among them — use it for their own network, and a /30 taken from it breaks their routes. A /30 that a route
//! of the machine already covers is skipped, and two namespaces of one test process never share one.

use std::process::Command;
use std::sync::atomic::{AtomicU32, Ordering};

/// How many namespaces this process has made, so that each gets a subnet of its own.
static MADE: AtomicU32 = AtomicU32::new(0);

/// Subnets of 198.18.0.0/15, as /30s.
const SUBNETS: u32 = 1 << 15;

/// The host and namespace addresses of /30 number `k` of 198.18.0.0/15.
fn subnet(k: u32) -> (String, String) {
    let base = (198u32 << 24) | (18 << 16) | ((k % SUBNETS) << 2);
    let dotted = |a: u32| format!("{}.{}.{}.{}", a >> 24, (a >> 16) & 255, (a >> 8) & 255, a & 255);
    (dotted(base + 1), dotted(base + 2))
}

/// The IPv4 routes of this machine, as printed by `ip -4 route`, to avoid any subnet they already cover.
fn routes() -> String {
    Command::new("ip")
        .args(["-4", "route", "show", "table", "all"])
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
        .unwrap_or_default()
}

/// Whether `route` (a line of `ip route`) covers address `addr`.
fn covers(route: &str, addr: &str) -> bool {
    let Some(dest) = route.split_whitespace().next() else { return false };
    let parse = |a: &str| a.parse::<std::net::Ipv4Addr>().ok().map(u32::from);
    let (net, len) = match dest.split_once('/') {
        Some((n, l)) => (n, l.parse::<u32>().unwrap_or(32)),
        None if dest == "default" => return false,
        None => (dest, 32),
    };
    let (Some(net), Some(a)) = (parse(net), parse(addr)) else { return false };
    let mask = if len == 0 { 0 } else { u32::MAX << (32 - len.min(32)) };
    net & mask == a & mask
}

pub struct Netns {
    name: String,
    host_if: String,
    pub host_addr: String,
    pub ns_addr: String,
}

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip").args(args).output().map_err(|e| format!("cannot run `ip`: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!("`ip {}` failed: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim()))
    }
}

impl Netns {
    /// Makes namespace `bt<pid><tag>` with a veth pair to this one, both ends up and addressed.
    pub fn new(tag: &str) -> Result<Netns, String> {
        let pid = std::process::id();
        let name = format!("bt{pid}{tag}");
        let (host_if, ns_if) = (format!("{name}h"), format!("{name}n"));
        if host_if.len() > 15 {
            return Err(format!("interface name {host_if} is too long; use a shorter tag"));
        }
        let routes = routes();
        let first = pid.wrapping_mul(16).wrapping_add(MADE.fetch_add(1, Ordering::Relaxed));
        let (host_addr, ns_addr) = (0..64)
            .map(|i| subnet(first.wrapping_add(i * 7919)))
            .find(|(h, n)| !routes.lines().any(|r| covers(r, h) || covers(r, n)))
            .ok_or("every subnet tried is already routed on this machine")?;
        ip(&["netns", "add", &name])?;
        let ns = Netns { name, host_if, host_addr, ns_addr };
        ip(&["link", "add", &ns.host_if, "type", "veth", "peer", "name", &ns_if])?;
        ip(&["link", "set", &ns_if, "netns", &ns.name])?;
        ip(&["addr", "add", &format!("{}/30", ns.host_addr), "dev", &ns.host_if])?;
        ip(&["link", "set", &ns.host_if, "up"])?;
        let exec = |args: &[&str]| {
            let mut all = vec!["netns", "exec", &ns.name, "ip"];
            all.extend_from_slice(args);
            ip(&all)
        };
        exec(&["addr", "add", &format!("{}/30", ns.ns_addr), "dev", &ns_if])?;
        exec(&["link", "set", &ns_if, "up"])?;
        exec(&["link", "set", "lo", "up"])?;
        Ok(ns)
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Cuts the cable: the host's end of the pair goes down, and nothing crosses.
    pub fn cut(&self) {
        ip(&["link", "set", &self.host_if, "down"]).expect("cut the link");
    }

    /// Plugs the cable back in.
    pub fn heal(&self) {
        ip(&["link", "set", &self.host_if, "up"]).expect("heal the link");
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        // Deleting the namespace deletes its end of the pair, and so the pair.
        let _ = ip(&["link", "del", &self.host_if]);
        let _ = ip(&["netns", "del", &self.name]);
    }
}
