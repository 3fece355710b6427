//! Publish-to-client latency over shared memory: the contract's state publisher and client
//! beside a bare iceoryx2 publisher/subscriber pair of the same payload, in one run.
//!
//! A publisher process writes, every period, one `MachineState` through `shm_api`'s
//! `StatePublisher` (as the coordinator does: loan, write in place, send, no notification) and
//! one through a bare iceoryx2 publisher on another service, which also notifies a bare event
//! service (what a bare event-driven pair does). Each sample carries its CLOCK_MONOTONIC send
//! time. The client process measures four phases, one after the other, `samples` each:
//! the contract's client busy-polling (`Client::next_busy`) and sleeping (`Client::next`), the
//! bare subscriber busy-polling, and the bare subscriber woken by the bare listener.

use std::fmt::Write as _;
use std::time::Duration;

use drivers::time::monotonic_now;
use hdrhistogram::Histogram;
use iceoryx2::prelude::*;
use shm_api::contract::MachineState;

/// One phase's figures, ns.
#[derive(Debug, Clone)]
pub struct Figures {
    /// The phase.
    pub name: &'static str,
    /// Samples measured.
    pub count: u64,
    /// Median, ns.
    pub median: u64,
    /// 99th percentile, ns.
    pub p99: u64,
    /// Maximum, ns.
    pub max: u64,
    /// Every latency, ns, in order (for plots).
    pub raw: Vec<u64>,
}

fn figures(name: &'static str, raw: Vec<u64>) -> Figures {
    let mut h = Histogram::<u64>::new_with_bounds(1, 60_000_000_000, 3).expect("bounds");
    for &v in &raw {
        let _ = h.record(v.max(1));
    }
    Figures {
        name,
        count: h.len(),
        median: h.value_at_quantile(0.5),
        p99: h.value_at_quantile(0.99),
        max: h.max(),
        raw,
    }
}

fn bare_names(prefix: &str) -> (ServiceName, ServiceName) {
    (
        format!("{prefix}-bare/state")
            .as_str()
            .try_into()
            .expect("name"),
        format!("{prefix}-bare/events")
            .as_str()
            .try_into()
            .expect("name"),
    )
}

/// The publisher process: publishes on both until `count` periods have passed.
pub fn publish(prefix: &str, period: Duration, count: u64) -> Result<(), String> {
    use shm_api::publisher::{
        CommandServer, EventPublisher, PublisherSettings, StatePublisher, create_node,
    };
    let node = create_node().map_err(|e| e.to_string())?;
    let names = shm_api::names::ServiceNames::new(prefix);
    let settings = PublisherSettings::default();
    let mut ours = StatePublisher::create(&node, &names, &settings).map_err(|e| e.to_string())?;
    // A client connects to all four services of the contract.
    let mut commands =
        CommandServer::create(&node, &names, &settings).map_err(|e| e.to_string())?;
    let _events = EventPublisher::create(&node, &names, &settings).map_err(|e| e.to_string())?;
    let (state_name, event_name) = bare_names(prefix);
    let bare_service = node
        .service_builder(&state_name)
        .publish_subscribe::<MachineState>()
        .history_size(1)
        .subscriber_max_buffer_size(settings.state_buffer)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(shm_api::words)?;
    let bare = bare_service
        .publisher_builder()
        .create()
        .map_err(shm_api::words)?;
    let bare_events = node
        .service_builder(&event_name)
        .event()
        .open_or_create()
        .map_err(shm_api::words)?;
    let notifier = bare_events
        .notifier_builder()
        .create()
        .map_err(shm_api::words)?;
    // The coordinator's relay: wakes after each period's publication and signals it.
    let published = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let start = monotonic_now();
    let relay = shm_api::publisher::spawn_state_relay(
        prefix.to_owned(),
        start.as_nanos(),
        period,
        Duration::from_micros(5),
        published.clone(),
        stop.clone(),
    )
    .map_err(|e| e.to_string())?;
    let mut next = start + period;
    // Publish on time, as the coordinator's real-time cycle thread does (SCHED_FIFO threads
    // have no timer slack): the default 50 µs slack would delay every publication.
    // SAFETY: prctl(PR_SET_TIMERSLACK) only changes this thread's timer slack.
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong);
    }
    for k in 0..count {
        // Alternate which goes first, so neither is always second.
        for which in [k % 2, 1 - k % 2] {
            if which == 0 {
                if let Ok(mut s) = ours.loan() {
                    s.cycle = k;
                    s.publish_time_ns = monotonic_now().as_nanos();
                    if s.send().is_ok() {
                        published.fetch_add(1, std::sync::atomic::Ordering::Release);
                    }
                }
            } else if let Ok(s) = bare.loan_uninit() {
                // SAFETY: MachineState is plain integers; all-zero is a valid value.
                let mut s = unsafe {
                    let mut s = s;
                    s.payload_mut().as_mut_ptr().write_bytes(0, 1);
                    s.assume_init()
                };
                s.cycle = k;
                s.publish_time_ns = monotonic_now().as_nanos();
                let _ = s.send();
                let _ = notifier.notify();
            }
        }
        // Commands are not part of the measurement; keep the server serviced.
        while commands.receive().is_some() {}
        let now = monotonic_now();
        if next > now {
            std::thread::sleep(next - now);
        }
        next += period;
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = relay.join();
    Ok(())
}

/// The client process: the four phases, `samples` each.
pub fn measure(prefix: &str, samples: usize) -> Result<Vec<Figures>, String> {
    let mut client = shm_api::client::Client::connect_timeout(prefix, Duration::from_secs(10))
        .map_err(|e| e.to_string())?;
    let node = NodeBuilder::new()
        .create::<ipc::Service>()
        .map_err(shm_api::words)?;
    let (state_name, event_name) = bare_names(prefix);
    let bare_service = node
        .service_builder(&state_name)
        .publish_subscribe::<MachineState>()
        .open()
        .map_err(shm_api::words)?;
    let bare = bare_service
        .subscriber_builder()
        .create()
        .map_err(shm_api::words)?;
    let listener = node
        .service_builder(&event_name)
        .event()
        .open()
        .map_err(shm_api::words)?
        .listener_builder()
        .create()
        .map_err(shm_api::words)?;
    let t = Duration::from_secs(2);
    let drain_bare = || while let Ok(Some(_)) = bare.receive() {};
    let mut out = Vec::new();

    // The contract's client, busy-polling.
    let _ = client.latest();
    let mut raw = Vec::with_capacity(samples);
    while raw.len() < samples {
        let s = client.next_busy(t).map_err(|e| e.to_string())?;
        raw.push(monotonic_now().as_nanos().saturating_sub(s.publish_time_ns));
    }
    out.push(figures("shm-api client, busy-poll", raw));

    // Bare iceoryx2 subscriber, busy-polling.
    drain_bare();
    let mut raw = Vec::with_capacity(samples);
    while raw.len() < samples {
        if let Ok(Some(s)) = bare.receive() {
            raw.push(monotonic_now().as_nanos().saturating_sub(s.publish_time_ns));
        } else {
            core::hint::spin_loop();
        }
    }
    out.push(figures("bare iceoryx2, busy-poll", raw));

    // The contract's client, sleeping between polls (Client::next).
    let _ = client.latest();
    let mut raw = Vec::with_capacity(samples);
    while raw.len() < samples {
        let s = client.next(t).map_err(|e| e.to_string())?;
        raw.push(monotonic_now().as_nanos().saturating_sub(s.publish_time_ns));
    }
    out.push(figures("shm-api client, sleeping (next)", raw));

    // The contract's client, event-driven: woken by the relay's signal.
    let _ = client.latest();
    let mut raw = Vec::with_capacity(samples);
    while raw.len() < samples {
        let s = client.next_event_driven(t).map_err(|e| e.to_string())?;
        raw.push(monotonic_now().as_nanos().saturating_sub(s.publish_time_ns));
    }
    out.push(figures("shm-api client, event-driven (relay)", raw));

    // Bare iceoryx2, woken by the publisher's notification.
    let _ = listener.try_wait(|_| {});
    drain_bare();
    let mut raw = Vec::with_capacity(samples);
    while raw.len() < samples {
        listener.timed_wait(|_| {}, t).map_err(shm_api::words)?;
        while let Ok(Some(s)) = bare.receive() {
            // One wake-up can bring several samples: exactly `samples` are kept.
            if raw.len() < samples {
                raw.push(monotonic_now().as_nanos().saturating_sub(s.publish_time_ns));
            }
        }
    }
    out.push(figures("bare iceoryx2, event-driven (listener)", raw));
    Ok(out)
}

/// Starts the publisher process (this executable's `shm-publisher` subcommand, `exe`) and
/// measures the five phases, `samples` each, at `period`; the publisher is stopped before this
/// returns.
pub fn run_with_publisher(
    exe: &std::path::Path,
    samples: usize,
    period: Duration,
) -> Result<Vec<Figures>, String> {
    let prefix = format!("timing-{}", std::process::id());
    // Enough periods for the five phases plus margin.
    let count = (samples as u64 * 5 + 4000).to_string();
    let mut publisher = std::process::Command::new(exe)
        .args(["shm-publisher", "--prefix", &prefix, "--period-us"])
        .arg(period.as_micros().to_string())
        .args(["--count", &count])
        .spawn()
        .map_err(|e| format!("starting the publisher: {e}"))?;
    let result = measure(&prefix, samples);
    let _ = publisher.kill();
    let _ = publisher.wait();
    result
}

/// The figures as a Markdown table, with the ratios to the bare pair.
pub fn table(f: &[Figures]) -> String {
    let mut s = String::from("| client | samples | median | p99 | max |\n|---|---|---|---|---|\n");
    for x in f {
        let _ = writeln!(
            s,
            "| {} | {} | {:.1} µs | {:.1} µs | {:.1} µs |",
            x.name,
            x.count,
            x.median as f64 / 1e3,
            x.p99 as f64 / 1e3,
            x.max as f64 / 1e3
        );
    }
    if f.len() == 5 {
        let r = |a: &Figures, b: &Figures| a.median as f64 / b.median.max(1) as f64;
        let _ = writeln!(
            s,
            "\nmedian ratios: busy-poll {:.2}x bare; event-driven (relay) {:.2}x bare event-driven; sleeping {:.2}x bare event-driven",
            r(&f[0], &f[1]),
            r(&f[3], &f[4]),
            r(&f[2], &f[4])
        );
    }
    s
}
