//! A network namespace joined to the test's own by a veth pair, for partitions that a real network makes: the
//! test owns it and deletes it (and the pair with it) when dropped. Making one needs root and iproute2; where
//! that fails, `Netns::new` says why, so that a test can say clearly that it skips.
//!
//! Addresses come from 192.0.2.0/24 (TEST-NET-1, reserved for documentation, never routed), one /30 per test
//! process, on the veth pair only.

use std::process::Command;

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
        let k = pid % 63;
        let host_addr = format!("192.0.2.{}", 4 * k + 1);
        let ns_addr = format!("192.0.2.{}", 4 * k + 2);
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
