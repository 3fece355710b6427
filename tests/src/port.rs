//! TCP ports on 127.0.0.1 for servers another process binds (a `drive-sim` CMMO-ST's Modbus
//! TCP server), chosen by a test before that process starts.
//!
//! A port from `bind("127.0.0.1:0")` lies in the kernel's ephemeral range and is free for
//! anyone from the moment the probe closes until the server binds it. In that window another
//! probe may be handed the same port, and its short-lived listener completes a client's
//! connect and then resets it (CI saw a test's first request to a starting drive-sim fail
//! with "connection reset by peer"); or an outgoing connection takes it as its source port
//! and the server's bind fails. The kernel hands out neither kind of port below its ephemeral
//! range, so the ports come from there: this process's id picks where in that range, a
//! counter moves on for each call, and a bind probe skips a port something already holds.
//!
//! This file is used by `integration-tests` (as `port`) and by the coordinator's own process
//! tests (by path), so both choose ports the same way.

use std::net::TcpListener;
use std::sync::atomic::{AtomicU32, Ordering};

/// The lowest port handed out: below it lie the registered services a developer's machine may
/// run.
const LOWEST: u32 = 10_000;
/// Ports between two processes' starting points, so that test binaries run at once (each
/// asks for a few ports) do not walk into each other.
const PER_PROCESS: u32 = 64;

/// A TCP port on 127.0.0.1 that nothing holds now, that this process has not handed out
/// before, and that the kernel will not hand to a probe or an outgoing connection.
pub fn server_port() -> u16 {
    static CALLS: AtomicU32 = AtomicU32::new(0);
    let top = ephemeral_low();
    let span = top.saturating_sub(LOWEST);
    assert!(
        span >= PER_PROCESS,
        "no ports below the ephemeral range ({top}) to choose from"
    );
    let start = std::process::id().wrapping_mul(PER_PROCESS) % span;
    loop {
        let n = CALLS.fetch_add(1, Ordering::Relaxed);
        assert!(n < span, "every port from {LOWEST} to {top} is taken");
        let port = u16::try_from(LOWEST + (start + n) % span).expect("below the ephemeral range");
        if TcpListener::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
}

/// The first port of the kernel's ephemeral range (`ip_local_port_range`; Linux's default
/// 32768 where it cannot be read).
fn ephemeral_low() -> u32 {
    std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(32_768)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ports_lie_below_the_ephemeral_range_and_are_not_repeated() {
        let ports: Vec<u16> = (0..8).map(|_| server_port()).collect();
        let low = ephemeral_low();
        for p in &ports {
            assert!(
                (LOWEST..low).contains(&u32::from(*p)),
                "{p} not below {low}"
            );
        }
        let mut unique = ports.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), ports.len(), "{ports:?}");
    }

    #[test]
    fn a_port_something_holds_is_skipped() {
        let first = server_port();
        // Hold the next few candidates, then ask: the answer is none of them.
        let held: Vec<TcpListener> = (1..4)
            .filter_map(|k| TcpListener::bind(("127.0.0.1", first + k)).ok())
            .collect();
        let next = server_port();
        for l in &held {
            assert_ne!(next, l.local_addr().unwrap().port());
        }
    }
}
