//! `timing publish`: how fast the real coordinator's state reaches a client process, beside a
//! bare iceoryx2 pair of the same payload, in one run.
//!
//! The run starts the coordinator as a user does (`coordinator run --shm-prefix P --quiet`: the
//! embedded default machine, its simulated drives, its demonstration) and, once its first state
//! is out, a bare publisher (this program's hidden `bare-publisher` subcommand) that every
//! period stamps CLOCK_MONOTONIC, loans a `MachineState`, writes it whole, sends it and notifies
//! a bare event service — the coordinator's publishing path without the machine. This process
//! is the client: in alternating windows (so all four see the same noise) it receives the
//! coordinator's states busy-polling (`Client::next_busy`) and event-driven
//! (`Client::next_event_driven`, woken by the cycle thread's notify), and the bare pair's
//! busy-polling and woken by a bare listener. Latency = receive time − the sample's
//! `publish_time_ns`. The coordinator's states also give "cycle to published"
//! (`publish_time_ns − sync_time_ns`), and its closing line gives what the notify costs the
//! cycle thread. Both processes are [`crate::child::Kept`]: stopped with SIGINT (the
//! coordinator's safe stop, the bare publisher's clean end), killed if they do not end.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use drivers::cli_number::Allowed;
use drivers::time::monotonic_now;
use iceoryx2::prelude::*;
use shm_api::contract::MachineState;

use crate::child::Kept;
use crate::report::summary::Run;
use crate::stats::Series;

/// The run's name in `summary.json`.
pub const NAME: &str = "publish";
/// Series: the coordinator's SYNC to its state sent.
pub const CYCLE_TO_PUBLISHED: &str = "cycle to published";
/// Series: coordinator → busy-polling client.
pub const OURS_BUSY: &str = "coordinator, busy-poll client";
/// Series: coordinator → event-driven client.
pub const OURS_EVENT: &str = "coordinator, event-driven client";
/// Series: bare publisher → busy-polling subscriber.
pub const BARE_BUSY: &str = "bare iceoryx2, busy-poll";
/// Series: bare publisher → subscriber woken by a bare listener.
pub const BARE_EVENT: &str = "bare iceoryx2, event-driven";
/// The goal: ours at most this many times the bare pair, p50 and p99.
pub const GOAL_RATIO: f64 = 1.3;

/// What `timing publish` measures for how long.
#[derive(Debug, Clone, PartialEq)]
pub struct PublishOptions {
    /// Measuring time, s, the four kinds' windows together (the coordinator's boot comes on
    /// top).
    pub duration_s: f64,
    /// One window, s.
    pub window_s: f64,
}

impl PublishOptions {
    /// Checks the numbers before anything starts.
    pub fn check(&self) -> Result<(), String> {
        Allowed::new("seconds", 0.4, 86_400.0).check_flag("--duration", self.duration_s)?;
        Allowed::new("seconds", 0.05, 60.0).check_flag("--window-s", self.window_s)?;
        if self.window_s * 4.0 > self.duration_s {
            return Err(format!(
                "--window-s {} with --duration {}: the duration must hold one window of each of \
                 the four kinds (at least {} s)",
                self.window_s,
                self.duration_s,
                self.window_s * 4.0
            ));
        }
        Ok(())
    }
}

fn bare_names(prefix: &str) -> Result<(ServiceName, ServiceName), String> {
    let name = |s: String| -> Result<ServiceName, String> {
        s.as_str()
            .try_into()
            .map_err(|e| format!("service name {s}: {}", shm_api::words(e)))
    };
    Ok((
        name(format!("{prefix}/state"))?,
        name(format!("{prefix}/events"))?,
    ))
}

/// The bare publisher process (`timing bare-publisher`): every `period`, at the cycle
/// thread's real-time priority where granted, stamps the time, loans a `MachineState`, zeroes
/// it, writes the stamp, sends it and notifies `PREFIX/events`, for at most `count` periods or
/// until SIGTERM / SIGINT.
pub fn bare_publisher(prefix: &str, period: Duration, count: u64) -> Result<(), String> {
    use coordinator::runtime::realtime_thread::{RealtimeSettings, enter_realtime};
    let node = shm_api::create_node_with(SignalHandlingMode::HandleTerminationRequests)
        .map_err(|e| e.to_string())?;
    let (state_name, event_name) = bare_names(prefix)?;
    let settings = shm_api::PublisherSettings::default();
    let publisher = node
        .service_builder(&state_name)
        .publish_subscribe::<MachineState>()
        .history_size(1)
        .subscriber_max_buffer_size(settings.state_buffer)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|e| format!("creating {prefix}/state: {}", shm_api::words(e)))?
        .publisher_builder()
        .max_loaned_samples(1)
        .create()
        .map_err(|e| format!("creating the bare publisher: {}", shm_api::words(e)))?;
    let notifier = node
        .service_builder(&event_name)
        .event()
        .open_or_create()
        .map_err(|e| format!("creating {prefix}/events: {}", shm_api::words(e)))?
        .notifier_builder()
        .create()
        .map_err(|e| format!("creating the bare notifier: {}", shm_api::words(e)))?;
    // The coordinator's cycle thread's priority and timer slack (1 ns), so neither side's
    // publisher is preempted more than the other.
    let _ = enter_realtime(&RealtimeSettings {
        lock_memory: false,
        ..RealtimeSettings::default()
    });
    let mut next = monotonic_now() + period;
    for k in 0..count {
        let now = monotonic_now();
        if next > now && node.wait(next - now).is_err() {
            break;
        }
        let stamp = monotonic_now().as_nanos();
        if let Ok(mut s) = publisher.loan_uninit() {
            // SAFETY: MachineState is plain integers (repr(C)); all-zero bytes are a valid
            // value, written in place as the coordinator's `StatePublisher::loan` does.
            let mut s = unsafe {
                s.payload_mut().as_mut_ptr().write_bytes(0, 1);
                s.assume_init()
            };
            s.cycle = k;
            s.sync_time_ns = next.as_nanos();
            s.publish_time_ns = stamp;
            s.cycle_ns = period.as_nanos() as u32;
            let _ = s.send();
            let _ = notifier.notify();
        }
        next += period;
    }
    Ok(())
}

/// One client kind, taking turns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    OursBusy,
    OursEvent,
    BareBusy,
    BareEvent,
}

const KINDS: [Kind; 4] = [
    Kind::OursBusy,
    Kind::BareBusy,
    Kind::OursEvent,
    Kind::BareEvent,
];

/// The bare pair's receiving side.
struct Bare {
    subscriber: iceoryx2::port::subscriber::Subscriber<ipc::Service, MachineState, ()>,
    listener: iceoryx2::port::listener::Listener<ipc::Service>,
    // Dropped after its ports.
    _node: Node<ipc::Service>,
}

impl Bare {
    /// Opens the bare services, retrying until `deadline` (the publisher creates them).
    fn open(prefix: &str, deadline: Instant) -> Result<Bare, String> {
        let node = shm_api::create_node().map_err(|e| e.to_string())?;
        let (state_name, event_name) = bare_names(prefix)?;
        loop {
            let tried = (|| {
                let subscriber = node
                    .service_builder(&state_name)
                    .publish_subscribe::<MachineState>()
                    .open()
                    .map_err(shm_api::words)?
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
                Ok::<_, String>((subscriber, listener))
            })();
            match tried {
                Ok((subscriber, listener)) => {
                    return Ok(Bare {
                        _node: node,
                        subscriber,
                        listener,
                    });
                }
                Err(e) if Instant::now() >= deadline => {
                    return Err(format!("opening the bare pair {prefix}: {e}"));
                }
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        }
    }

    fn drain(&self) {
        while let Ok(Some(_)) = self.subscriber.receive() {}
        let _ = self.listener.try_wait(|_| {});
    }
}

/// What the client measured.
struct Measured {
    series: [Series; 5],
    windows: u64,
}

fn since(t0: Instant) -> u64 {
    t0.elapsed().as_nanos() as u64
}

/// Measures the four kinds in turns of `window` for `duration`.
fn measure(
    client: &mut shm_api::Client,
    bare: &Bare,
    coordinator: &mut Kept,
    o: &PublishOptions,
) -> Result<Measured, String> {
    let mut series = [
        Series::new(CYCLE_TO_PUBLISHED),
        Series::new(OURS_BUSY),
        Series::new(OURS_EVENT),
        Series::new(BARE_BUSY),
        Series::new(BARE_EVENT),
    ];
    let window = Duration::from_secs_f64(o.window_s);
    let windows = ((o.duration_s / o.window_s).round() as u64).max(4);
    let mut progress = crate::progress::Progress::new(NAME, windows);
    let t0 = Instant::now();
    let mut last = 0u64;
    for w in 0..windows {
        if !coordinator.alive() {
            progress.finish();
            return Err(coordinator.failed("the coordinator ended during the measurement"));
        }
        let kind = KINDS[(w % 4) as usize];
        let end = Instant::now() + window;
        match kind {
            Kind::OursBusy | Kind::OursEvent => {
                let _ = client.latest();
                loop {
                    let left = end.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        break;
                    }
                    let got = if kind == Kind::OursBusy {
                        client.next_busy(left)
                    } else {
                        client.next_event_driven(left)
                    };
                    let s = match got {
                        Ok(s) => s,
                        Err(shm_api::ClientError::Timeout) => break,
                        Err(e) => {
                            progress.finish();
                            return Err(coordinator
                                .failed(&format!("receiving the coordinator's state: {e}")));
                        }
                    };
                    let now = monotonic_now().as_nanos();
                    let t = since(t0);
                    let i = if kind == Kind::OursBusy { 1 } else { 2 };
                    series[i].record(t, now.saturating_sub(s.publish_time_ns));
                    if s.cycle != last {
                        last = s.cycle;
                        series[0].record(t, s.publish_time_ns.saturating_sub(s.sync_time_ns));
                    }
                }
            }
            Kind::BareBusy => {
                bare.drain();
                while Instant::now() < end {
                    match bare.subscriber.receive() {
                        Ok(Some(s)) => {
                            let now = monotonic_now().as_nanos();
                            series[3].record(since(t0), now.saturating_sub(s.publish_time_ns));
                        }
                        _ => core::hint::spin_loop(),
                    }
                }
            }
            Kind::BareEvent => {
                bare.drain();
                loop {
                    let left = end.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        break;
                    }
                    bare.listener.timed_wait(|_| {}, left).map_err(|e| {
                        format!("waiting on the bare listener: {}", shm_api::words(e))
                    })?;
                    while let Ok(Some(s)) = bare.subscriber.receive() {
                        let now = monotonic_now().as_nanos();
                        series[4].record(since(t0), now.saturating_sub(s.publish_time_ns));
                    }
                }
            }
        }
        progress.set(w + 1);
    }
    progress.finish();
    Ok(Measured { series, windows })
}

/// The figures of the coordinator's `state notify:` line: (calls, failed, median µs, p99 µs,
/// max µs).
pub fn parse_notify_line(output: &str) -> Option<(u64, u64, f64, f64, f64)> {
    let line = output
        .lines()
        .rev()
        .find_map(|l| l.trim().strip_prefix("state notify: "))?;
    let words: Vec<&str> = line.split([' ', ',']).filter(|w| !w.is_empty()).collect();
    let after = |key: &str| -> Option<&str> {
        words
            .iter()
            .position(|w| *w == key)
            .and_then(|i| words.get(i + 1).copied())
    };
    let before = |key: &str| -> Option<&str> {
        words
            .iter()
            .position(|w| *w == key)
            .and_then(|i| i.checked_sub(1))
            .and_then(|i| words.get(i).copied())
    };
    Some((
        before("calls")?.parse().ok()?,
        before("failed")?.parse().ok()?,
        after("median")?.parse().ok()?,
        after("p99")?.parse().ok()?,
        after("max")?.parse().ok()?,
    ))
}

/// The whole run: starts the coordinator and the bare publisher, measures, stops both, and
/// returns the run for the report.
pub fn run(exe: &Path, o: &PublishOptions) -> Result<(Run, Vec<Series>), String> {
    o.check()?;
    let coordinator_exe = crate::binaries::beside(exe, "coordinator")?;
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let prefix = format!("timing-publish-{}-{stamp}", std::process::id());
    let bare_prefix = format!("{prefix}-bare");
    let mut cmd = Command::new(&coordinator_exe);
    cmd.args(["run", "--quiet", "--shm-prefix", &prefix]);
    let mut coordinator = Kept::spawn("the coordinator", cmd)?;
    // The boot (drives reset, homing) comes before the first state; a debug build is slow.
    let client = shm_api::Client::connect_timeout(&prefix, Duration::from_secs(60));
    let mut client = match client {
        Ok(c) => c,
        Err(e) => {
            coordinator.stop(Duration::from_secs(10));
            return Err(coordinator.failed(&format!(
                "connecting to the coordinator under {prefix}: {e}"
            )));
        }
    };
    let first = match client.next(Duration::from_secs(30)) {
        Ok(s) => *s,
        Err(e) => {
            coordinator.stop(Duration::from_secs(10));
            return Err(coordinator.failed(&format!("the coordinator's first state: {e}")));
        }
    };
    let period_ns = u64::from(first.cycle_ns).max(1);
    let period_us = period_ns / 1000;
    // Enough periods for the run and a margin; SIGINT ends it sooner.
    let count = ((o.duration_s + 60.0) * 1e9 / period_ns as f64) as u64;
    let mut cmd = Command::new(exe);
    cmd.args(["bare-publisher", "--prefix", &bare_prefix, "--period-ns"])
        .arg(period_ns.to_string())
        .args(["--count", &count.to_string()]);
    let mut bare_proc = match Kept::spawn("the bare publisher", cmd) {
        Ok(b) => b,
        Err(e) => {
            coordinator.stop(Duration::from_secs(10));
            return Err(e);
        }
    };
    let measured = Bare::open(&bare_prefix, Instant::now() + Duration::from_secs(10))
        .map_err(|e| bare_proc.failed(&e))
        .and_then(|bare| {
            let m = measure(&mut client, &bare, &mut coordinator, o);
            drop(bare);
            m
        });
    drop(client);
    let bare_status = bare_proc.stop(Duration::from_secs(5));
    // The coordinator's safe stop takes up to 6 s (stop the axes, disable the drives).
    let status = coordinator.stop(Duration::from_secs(20));
    let text = coordinator.output();
    let measured = measured?;
    // 2: the run completed but reported faults or boot failures (a starved simulated drive on
    // a loaded host): the latencies stand, the note says so.
    if !matches!(status, Some(0) | Some(2)) {
        return Err(coordinator.failed(&format!(
            "the coordinator ended with status {} after SIGINT",
            status.map_or("none (killed)".into(), |c| c.to_string())
        )));
    }
    if bare_status != Some(0) {
        return Err(bare_proc.failed(&format!(
            "the bare publisher ended with status {}",
            bare_status.map_or("none (killed)".into(), |c| c.to_string())
        )));
    }
    let notify = parse_notify_line(&text)
        .ok_or_else(|| coordinator.failed("the coordinator printed no `state notify:` line"))?;

    let mut run = Run::new(
        NAME,
        &format!(
            "state to client: coordinator vs bare iceoryx2, {} B every {period_us} µs",
            core::mem::size_of::<MachineState>()
        ),
    );
    run.set("duration_s", o.duration_s);
    run.set("window_s", o.window_s);
    run.set("windows", measured.windows);
    run.set("period_us", period_us);
    run.set("payload_bytes", core::mem::size_of::<MachineState>() as u64);
    run.set("notify_calls", notify.0);
    run.set("notify_failed", notify.1);
    run.set("notify_p50_us", notify.2);
    run.set("notify_p99_us", notify.3);
    run.set("notify_max_us", notify.4);
    run.baselines
        .insert("bare iceoryx2 pair".into(), "ran".into());
    run.notes.push(format!(
        "the coordinator has no period option: the embedded default machine's {period_us} µs \
         period is used, and the bare publisher publishes at the same period"
    ));
    run.notes.push(format!(
        "the cycle thread's notify (what waking event-driven clients costs each cycle): median \
         {:.2} µs, p99 {:.2} µs, max {:.2} µs over {} cycles, {} failed (the coordinator's \
         `state notify:` line)",
        notify.2, notify.3, notify.4, notify.0, notify.1
    ));
    if status == Some(2) {
        let faults: Vec<&str> = text
            .lines()
            .map(str::trim)
            .filter(|l| l.starts_with("fault:") || l.starts_with("refused:"))
            .collect();
        run.notes.push(format!(
            "the coordinator reported faults (exit status 2), the machine's, not the \
             measurement's: {}",
            faults.join("; ")
        ));
    }
    for s in &measured.series {
        run.add(s, None);
    }
    for (ours, bare) in [(OURS_BUSY, BARE_BUSY), (OURS_EVENT, BARE_EVENT)] {
        run.add_ratios(ours, bare, &["p50", "p99"]);
    }
    for (ours, bare, kind) in [
        (OURS_BUSY, BARE_BUSY, "busy-poll"),
        (OURS_EVENT, BARE_EVENT, "event-driven"),
    ] {
        for f in ["p50", "p99"] {
            run.goal_ratio(
                &format!("{kind} client {f} at most {GOAL_RATIO}x the bare iceoryx2 pair's"),
                ours,
                bare,
                f,
                GOAL_RATIO,
            );
        }
    }
    Ok((run, measured.series.into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_notify_line_is_read_back() {
        let out = "boot...\nstate notify: 1500 calls, 2 failed, median 1.90 µs, p99 4.10 µs, \
                   max 23.00 µs (the cycle thread's wake-up of event-driven clients, after each \
                   state)\nsummary";
        assert_eq!(parse_notify_line(out), Some((1500, 2, 1.9, 4.1, 23.0)));
        assert_eq!(parse_notify_line("nothing"), None);
    }

    #[test]
    fn options_are_checked_naming_the_option() {
        let ok = PublishOptions {
            duration_s: 10.0,
            window_s: 0.5,
        };
        assert!(ok.check().is_ok());
        for (d, w, word) in [
            (f64::NAN, 0.5, "--duration"),
            (0.1, 0.05, "--duration"),
            (10.0, 0.0, "--window-s"),
            (1.0, 0.5, "four kinds"),
        ] {
            let e = PublishOptions {
                duration_s: d,
                window_s: w,
            }
            .check()
            .unwrap_err();
            assert!(e.contains(word), "{e}");
        }
    }
}
