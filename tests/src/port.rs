//! TCP ports on 127.0.0.1 for servers another process binds (a `drive-sim` CMMO-ST's Modbus
//! TCP server), chosen by a test before that process starts.
//!
//! A port is probed by binding a socket to it **without listening**. A listening probe, as
//! `TcpListener::bind` makes, is open for only microseconds, but a test running beside this one
//! may fork to start its own process in that moment: the child holds a copy of the listener
//! until its exec closes it, milliseconds later on a busy host. A client dialling the port
//! then is accepted by that copy and reset when it closes (seen here: a test's first request to
//! a starting drive-sim got "connection reset by peer", and drive-sim counted no connection).
//! A socket that is only bound accepts nothing; with `SO_REUSEADDR`, as a server sets it, it
//! does not keep the server from binding either.
//!
//! The ports lie below the kernel's ephemeral range, which it never hands to `bind` on port 0
//! or to an outgoing connection: otherwise one of those could take the port between the
//! test's choice and the server's bind. This process's id picks where in that range to start,
//! a counter moves on for each call, and a port something holds is skipped.
//!
//! This file is used by `integration-tests` (as `port`) and by the coordinator's own process
//! tests (by path), so both choose ports the same way.

use std::net::{Ipv4Addr, SocketAddrV4};
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
    let candidates = core::iter::from_fn(|| {
        let n = CALLS.fetch_add(1, Ordering::Relaxed);
        assert!(n < span, "every port from {LOWEST} to {top} is taken");
        Some(u16::try_from(LOWEST + (start + n) % span).expect("below the ephemeral range"))
    });
    first_free(candidates).expect("the candidates never end")
}

/// The first of `ports` a server could bind on 127.0.0.1 now.
fn first_free(ports: impl IntoIterator<Item = u16>) -> Option<u16> {
    ports.into_iter().find(|&port| bound_only(port).is_ok())
}

/// A socket bound to 127.0.0.1:`port` as a server binds it (`SO_REUSEADDR`) that never
/// listens (and is close-on-exec), so it accepts nothing, even in a forked child's copy.
fn bound_only(port: u16) -> std::io::Result<socket2::Socket> {
    use socket2::{Domain, Socket, Type};
    let s = Socket::new(Domain::IPV4, Type::STREAM, None)?;
    s.set_reuse_address(true)?;
    s.bind(&SocketAddrV4::new(Ipv4Addr::LOCALHOST, port).into())?;
    Ok(s)
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
    use std::net::TcpListener;

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
        // Ports from the ephemeral range, which `server_port` never hands out: holding one of
        // its own range here could catch a connection meant for a drive-sim of a test running
        // beside this one (the file is built into such test binaries too).
        let held = TcpListener::bind("127.0.0.1:0").unwrap();
        let held_port = held.local_addr().unwrap().port();
        // Bound without listening, as `first_free` probes: a copy a forked child may hold for a
        // moment does not make the port look taken.
        let freed = bound_only(0).unwrap();
        let freed_port = freed.local_addr().unwrap().as_socket().unwrap().port();
        drop(freed);
        assert_eq!(first_free([held_port]), None);
        assert_eq!(first_free([held_port, freed_port]), Some(freed_port));
    }
}
