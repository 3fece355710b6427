//! Real-time thread primitives (Linux): the absolute-deadline [`Ticker`], [`enter_realtime`]
//! (memory locking, SCHED_FIFO, CPU affinity), the SIGINT/SIGTERM [`stop_flag`], and a
//! wait-free [`triple_buffer`] for handing values between the cycle thread and an I/O thread.
//!
//! Nothing here fails hard when the system refuses real-time privileges: the coordinator must
//! still run (slower, with jitter) on a developer machine, and say clearly what was refused and
//! how to grant it.
//!
//! `unsafe` appears only around libc calls and in the triple buffer's slot access, each with
//! its `SAFETY` argument.

use std::cell::UnsafeCell;
use std::fmt;
use std::io;
use std::sync::Arc;
use std::sync::Once;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::time::Duration;

use drivers::time::{Instant, monotonic_now};

/// One wake-up of a [`Ticker`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tick {
    /// Index of this deadline since the start: `deadline = start + cycle * period`. Skipped
    /// deadlines are counted, so the number keeps mapping to time.
    pub cycle: u64,
    /// The deadline slept to.
    pub deadline: Instant,
    /// When the thread ran again (never before `deadline`).
    pub woke: Instant,
    /// `woke - deadline`: the wake-up latency (or how late the caller came back).
    pub late: Duration,
    /// Deadlines given up on before this one because the caller came back more than a period
    /// late (0 normally).
    pub skipped: u64,
}

/// Periodic wake-up on absolute deadlines of `CLOCK_MONOTONIC`
/// (`clock_nanosleep(TIMER_ABSTIME)`): the period does not drift with the time spent working,
/// and a late wake-up does not shift later ones.
///
/// A caller that comes back more than one period after a deadline skips the deadlines it
/// missed (counted in [`Tick::skipped`]) instead of running a burst of catch-up cycles: a
/// motion cycle that runs twice back to back would send two setpoints in one bus period.
#[derive(Debug, Clone)]
pub struct Ticker {
    start: Instant,
    period: Duration,
    cycle: u64,
}

impl Ticker {
    /// A ticker whose first deadline is `start` (usually `monotonic_now()` plus a margin),
    /// then every `period` (a zero period is taken as 1 ns).
    pub fn new(start: Instant, period: Duration) -> Ticker {
        Ticker {
            start,
            period: period.max(Duration::from_nanos(1)),
            cycle: 0,
        }
    }

    /// The period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// The next deadline [`wait`](Self::wait) sleeps to (before any skipping).
    pub fn next_deadline(&self) -> Instant {
        self.deadline_of(self.cycle)
    }

    fn deadline_of(&self, cycle: u64) -> Instant {
        let ns = u128::from(cycle) * self.period.as_nanos();
        self.start + Duration::from_nanos(u64::try_from(ns).unwrap_or(u64::MAX))
    }

    /// Skips the deadlines more than one period before `now`; returns how many. Afterwards the
    /// next deadline is later than `now - period`.
    fn skip_missed(&mut self, now: Instant) -> u64 {
        let behind = now.saturating_duration_since(self.next_deadline());
        if behind <= self.period {
            return 0;
        }
        let k = u64::try_from(behind.as_nanos() / self.period.as_nanos()).unwrap_or(u64::MAX);
        self.cycle = self.cycle.saturating_add(k);
        k
    }

    /// Sleeps until the next deadline (at once if it has passed) and returns what happened.
    pub fn wait(&mut self) -> Tick {
        self.wait_with(sleep_until)
    }

    /// [`wait`](Self::wait), sleeping with `sleep` (tests stall inside it).
    fn wait_with(&mut self, sleep: impl FnOnce(Instant)) -> Tick {
        let mut skipped = self.skip_missed(monotonic_now());
        let mut deadline = self.next_deadline();
        sleep(deadline);
        let woke = monotonic_now();
        // Stopped while asleep (the host stalled the thread, SIGSTOP): the deadlines that passed
        // meanwhile are missed too, now and not only at the next wait, and this cycle is the
        // latest deadline's. Otherwise the first cycle after the stall ran as if on time, with
        // a `now` from before it (its guarding polls stamped then, their replies judged against
        // that time), and the overrun was noticed a cycle later.
        let missed = self.skip_missed(woke);
        if missed > 0 {
            skipped += missed;
            deadline = self.next_deadline();
        }
        let tick = Tick {
            cycle: self.cycle,
            deadline,
            woke,
            late: woke.saturating_duration_since(deadline),
            skipped,
        };
        self.cycle = self.cycle.saturating_add(1);
        tick
    }
}

/// Sleeps on `CLOCK_MONOTONIC` until `deadline`, retrying after signals.
pub fn sleep_until(deadline: Instant) {
    let ns = deadline.as_nanos();
    let ts = libc::timespec {
        tv_sec: (ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: `ts` is a valid timespec for the duration of the call; the remaining-time
        // pointer may be null with TIMER_ABSTIME.
        let rc = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        // clock_nanosleep returns the error number itself. EINTR: a signal (e.g. the stop
        // flag's) woke us early; sleep the rest. Anything else (EINVAL) cannot be slept away.
        if rc != libc::EINTR {
            break;
        }
    }
    // The guarantee callers rely on: never return before the deadline, even after an error.
    while monotonic_now() < deadline {
        std::hint::spin_loop();
    }
}

/// What [`enter_realtime`] asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RtSettings {
    /// SCHED_FIFO priority (1..=99; 80 by default: above the kernel's threaded IRQ handlers at
    /// 50, below the watchdogs at 99). `None`: stay on the normal scheduler.
    pub priority: Option<i32>,
    /// Pin the calling thread to this CPU.
    pub cpu: Option<usize>,
    /// `mlockall(MCL_CURRENT | MCL_FUTURE)` and touch some stack, so no page fault hits the
    /// cycle.
    pub lock_memory: bool,
}

impl Default for RtSettings {
    fn default() -> Self {
        RtSettings {
            priority: Some(80),
            cpu: None,
            lock_memory: true,
        }
    }
}

/// What [`enter_realtime`] obtained. `Display` prints one line of what was granted, then one
/// line per warning.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RtReport {
    /// Memory is locked.
    pub memory_locked: bool,
    /// The SCHED_FIFO priority in force, if granted.
    pub fifo_priority: Option<i32>,
    /// The CPU the thread is pinned to, if granted.
    pub cpu: Option<usize>,
    /// One sentence per refusal: what was refused (with the errno), what it costs and how to
    /// grant it.
    pub warnings: Vec<String>,
}

impl RtReport {
    /// Everything asked for was granted.
    pub fn is_complete(&self) -> bool {
        self.warnings.is_empty()
    }
}

impl fmt::Display for RtReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "real-time: memory {}, scheduler {}, cpu {}",
            if self.memory_locked {
                "locked"
            } else {
                "not locked"
            },
            match self.fifo_priority {
                Some(p) => format!("SCHED_FIFO {p}"),
                None => "normal".into(),
            },
            match self.cpu {
                Some(c) => c.to_string(),
                None => "any".into(),
            }
        )?;
        for w in &self.warnings {
            write!(f, "\nwarning: {w}")?;
        }
        Ok(())
    }
}

/// `EPERM: Operation not permitted (os error 1)`: the symbolic name is what people search for.
fn errno_text(e: &io::Error) -> String {
    let name = match e.raw_os_error() {
        Some(libc::EPERM) => "EPERM: ",
        Some(libc::ENOMEM) => "ENOMEM: ",
        Some(libc::EINVAL) => "EINVAL: ",
        Some(libc::EAGAIN) => "EAGAIN: ",
        Some(libc::ESRCH) => "ESRCH: ",
        _ => "",
    };
    format!("{name}{e}")
}

fn rlimit(resource: libc::__rlimit_resource_t) -> Option<libc::rlim_t> {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes one rlimit into the valid, exclusively borrowed `r`.
    let rc = unsafe { libc::getrlimit(resource, &mut r) };
    (rc == 0).then_some(r.rlim_cur)
}

fn limit_text(v: Option<libc::rlim_t>) -> String {
    match v {
        Some(libc::RLIM_INFINITY) => "unlimited".into(),
        Some(v) => v.to_string(),
        None => "unknown".into(),
    }
}

/// Touches this much stack once memory is locked, so the cycle's deepest calls find it
/// resident.
const PREFAULT_STACK: usize = 64 * 1024;

#[inline(never)]
fn prefault_stack() {
    let mut page = [0u8; PREFAULT_STACK];
    for b in page.iter_mut().step_by(4096) {
        *b = 1;
    }
    std::hint::black_box(&mut page);
}

/// Makes the calling thread the real-time cycle thread as far as the system allows: locks
/// memory, switches to SCHED_FIFO, pins the CPU. Each refusal becomes a warning in the report,
/// never an error: the coordinator still runs, with more jitter.
pub fn enter_realtime(settings: &RtSettings) -> RtReport {
    let mut report = RtReport::default();
    if settings.lock_memory {
        // SAFETY: mlockall takes flags only and touches no memory of ours.
        let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
        if rc == 0 {
            report.memory_locked = true;
            prefault_stack();
        } else {
            let e = io::Error::last_os_error();
            report.warnings.push(format!(
                "mlockall(MCL_CURRENT|MCL_FUTURE) refused: {}; memory can be paged out and a \
                 page fault can stall a cycle. The locked-memory limit is {} bytes: raise it \
                 (`ulimit -l unlimited`, memlock in /etc/security/limits.conf) or grant \
                 CAP_IPC_LOCK.",
                errno_text(&e),
                limit_text(rlimit(libc::RLIMIT_MEMLOCK)),
            ));
        }
    }
    if let Some(priority) = settings.priority {
        let param = libc::sched_param {
            sched_priority: priority,
        };
        // SAFETY: pid 0 is the calling thread on Linux; `param` is valid during the call.
        let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
        if rc == 0 {
            report.fifo_priority = Some(priority);
        } else {
            let e = io::Error::last_os_error();
            let why = if e.raw_os_error() == Some(libc::EINVAL) {
                "SCHED_FIFO priorities are 1..=99.".to_string()
            } else {
                format!(
                    "The real-time priority limit is {}: raise it (`ulimit -r 99`, rtprio in \
                     /etc/security/limits.conf) or grant CAP_SYS_NICE (e.g. `setcap \
                     cap_sys_nice,cap_ipc_lock+ep` on the binary).",
                    limit_text(rlimit(libc::RLIMIT_RTPRIO))
                )
            };
            report.warnings.push(format!(
                "SCHED_FIFO priority {priority} refused: {}; the cycle thread stays on the \
                 normal scheduler and any process can delay it. {why}",
                errno_text(&e),
            ));
        }
    }
    if let Some(cpu) = settings.cpu {
        match pin_to_cpu(cpu) {
            Ok(()) => report.cpu = Some(cpu),
            Err(e) => report.warnings.push(format!(
                "pinning to CPU {cpu} refused: {}; the thread may migrate between CPUs. Choose \
                 a CPU this process may use (see `taskset -p $$` and isolcpus).",
                errno_text(&e)
            )),
        }
    }
    report
}

/// Puts the calling thread back on the normal scheduler (SCHED_OTHER) once its real-time part
/// is over: tearing down ports and shared memory takes milliseconds of CPU in a debug build,
/// which at SCHED_FIFO keeps every real-time thread of lower or equal priority on the machine
/// (other processes' drives included) off that CPU. Refused only for an invalid policy, never.
pub fn leave_realtime() {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pid 0 is the calling thread on Linux; `param` is valid during the call.
    let _ = unsafe { libc::sched_setscheduler(0, libc::SCHED_OTHER, &param) };
}

fn pin_to_cpu(cpu: usize) -> io::Result<()> {
    // CPU_SET indexes a fixed-size bit array; refuse what does not fit rather than panic.
    if cpu >= libc::CPU_SETSIZE as usize {
        return Err(io::Error::from_raw_os_error(libc::EINVAL));
    }
    // SAFETY: cpu_set_t is plain bits; all-zero is the empty set.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    // SAFETY: `cpu` is below CPU_SETSIZE, checked above.
    unsafe { libc::CPU_SET(cpu, &mut set) };
    // SAFETY: pid 0 is the calling thread; `set` is valid and its size is passed.
    let rc = unsafe { libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

static STOP: AtomicBool = AtomicBool::new(false);
static INSTALL: Once = Once::new();

/// The flag SIGINT, SIGTERM, SIGHUP (the terminal closed) and SIGQUIT set: each leads to the same
/// safe stop. The first call installs the handlers (signal-hook's `flag` module: the handler
/// only stores to the atomic, which is async-signal-safe). The run loop polls it each cycle,
/// stops the axes with their configured deceleration, disables the drives and publishes the
/// state before leaving (bounded: at most 3 s for the stop and 3 s for the disable, see
/// `runtime::script`). A second SIGINT while the flag is set ends the process at once (exit
/// status 130), for a shutdown that hangs.
pub fn stop_flag() -> &'static AtomicBool {
    INSTALL.call_once(|| {
        use signal_hook::consts::{SIGHUP, SIGINT, SIGQUIT, SIGTERM};
        // Registration fails only for the forbidden signals (SIGKILL, SIGSTOP...), not for
        // these; there is nothing useful to do with an error here.
        let _ = signal_hook::flag::register_conditional_shutdown(SIGINT, 130, &STOP);
        for sig in [SIGINT, SIGTERM, SIGHUP, SIGQUIT] {
            let _ = signal_hook::flag::register(sig, &STOP);
        }
    });
    &STOP
}

/// The three slots of a triple buffer and the index of the middle one. The writer and the
/// reader each own one slot; the third (the middle) is handed over with one atomic swap.
struct Slots<T> {
    slots: [UnsafeCell<T>; 3],
    /// Bits 0..1: index of the middle slot; [`FRESH`]: it holds a value the reader has not
    /// taken.
    middle: AtomicU8,
}

const INDEX: u8 = 0b11;
const FRESH: u8 = 0b100;

// SAFETY: the index protocol gives each slot to exactly one side at a time (the writer's
// index, the middle index and the reader's index are always a permutation of 0, 1, 2), and the
// AcqRel swaps order every slot write before the hand-over; so sharing `Slots` between the two
// threads only ever moves `T` values between them, which `T: Send` allows.
unsafe impl<T: Send> Sync for Slots<T> {}

impl<T> Slots<T> {
    fn slot(&self, i: u8) -> *mut T {
        // The modulo keeps a corrupted index from panicking; it cannot occur (see above).
        self.slots[usize::from(i % 3)].get()
    }
}

/// The writing half of a [`triple_buffer`]. Wait-free: never blocks, never allocates.
pub struct TripleWriter<T> {
    shared: Arc<Slots<T>>,
    index: u8,
}

/// The reading half of a [`triple_buffer`]. Wait-free: never blocks, never allocates.
pub struct TripleReader<T> {
    shared: Arc<Slots<T>>,
    index: u8,
}

impl<T> fmt::Debug for TripleWriter<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TripleWriter").finish_non_exhaustive()
    }
}

impl<T> fmt::Debug for TripleReader<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TripleReader").finish_non_exhaustive()
    }
}

/// A single-writer, single-reader "latest value" channel: the writer publishes whole values,
/// the reader gets the latest one published, never a torn mix, and neither ever waits for the
/// other (unlike a seqlock, whose reader retries while a write is in progress). Values
/// published between two reads are overwritten: this carries state, not events.
///
/// Written here rather than taken from the `triple_buffer` crate: it is 40 lines, and the
/// cycle side must be provably free of locks and allocation.
pub fn triple_buffer<T: Copy + Send>(initial: T) -> (TripleWriter<T>, TripleReader<T>) {
    let shared = Arc::new(Slots {
        slots: [
            UnsafeCell::new(initial),
            UnsafeCell::new(initial),
            UnsafeCell::new(initial),
        ],
        middle: AtomicU8::new(1),
    });
    (
        TripleWriter {
            shared: Arc::clone(&shared),
            index: 0,
        },
        TripleReader { shared, index: 2 },
    )
}

impl<T: Copy> TripleWriter<T> {
    /// Publishes `value`: the reader's next [`read`](TripleReader::read) returns it (or a later
    /// one).
    pub fn publish(&mut self, value: T) {
        // SAFETY: slot `self.index` belongs to the writer alone until the swap below.
        unsafe { self.shared.slot(self.index).write(value) };
        // Release: the write above is visible to the reader that acquires this slot.
        let old = self
            .shared
            .middle
            .swap(self.index | FRESH, Ordering::AcqRel);
        self.index = old & INDEX;
    }
}

impl<T: Copy> TripleReader<T> {
    /// The latest value published, and whether it is new since the last call.
    pub fn read(&mut self) -> (T, bool) {
        let fresh = self.shared.middle.load(Ordering::Relaxed) & FRESH != 0;
        if fresh {
            // Acquire: pairs with the writer's release; the slot received is complete.
            let old = self.shared.middle.swap(self.index, Ordering::AcqRel);
            self.index = old & INDEX;
        }
        // SAFETY: slot `self.index` belongs to the reader alone until it swaps it away.
        (unsafe { self.shared.slot(self.index).read() }, fresh)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wake_ups_are_in_order_and_never_early() {
        let period = Duration::from_millis(1);
        let mut t = Ticker::new(monotonic_now() + period, period);
        let mut last: Option<Tick> = None;
        for _ in 0..30 {
            let tick = t.wait();
            assert!(tick.woke >= tick.deadline, "{tick:?}");
            assert_eq!(tick.late, tick.woke - tick.deadline);
            if let Some(prev) = last {
                assert!(tick.cycle > prev.cycle);
                assert!(tick.deadline > prev.deadline);
                assert!(tick.woke >= prev.woke);
                // Deadlines stay on the grid, whatever the wake-up latency.
                let steps = u32::try_from(tick.cycle - prev.cycle).unwrap();
                assert_eq!(tick.deadline - prev.deadline, period * steps);
            }
            last = Some(tick);
        }
    }

    #[test]
    fn a_stalled_caller_skips_instead_of_bursting() {
        // A period well above this shared host's scheduling noise (tens of ms under load), so
        // that only the ticker's logic is checked, not the machine's latency.
        let period = Duration::from_millis(50);
        let mut t = Ticker::new(monotonic_now(), period);
        let first = t.wait();
        // Stall for ten periods.
        std::thread::sleep(period * 10);
        let resumed = t.wait();
        assert!(resumed.skipped >= 8, "{resumed:?}");
        assert_eq!(resumed.cycle, first.cycle + 1 + resumed.skipped);
        // The deadline taken is less than one period past: no catch-up burst follows.
        assert!(resumed.late < period, "{resumed:?}");
        let next = t.wait();
        assert_eq!(next.skipped, 0);
        assert_eq!(next.deadline - resumed.deadline, period);
        assert!(next.woke >= next.deadline);
    }

    #[test]
    fn a_stall_during_the_sleep_is_skipped_at_once() {
        let period = Duration::from_millis(50);
        let mut t = Ticker::new(monotonic_now(), period);
        let first = t.wait();
        // Asleep toward the next deadline, the thread is stopped for ten periods.
        let resumed = t.wait_with(|d| {
            sleep_until(d);
            std::thread::sleep(period * 10);
        });
        assert!(resumed.skipped >= 8, "{resumed:?}");
        assert_eq!(resumed.cycle, first.cycle + 1 + resumed.skipped);
        assert!(resumed.late < period, "{resumed:?}");
        let next = t.wait();
        assert_eq!(next.skipped, 0, "{next:?}");
        assert_eq!(next.deadline - resumed.deadline, period);
    }

    #[test]
    fn skipping_is_exact_on_the_grid() {
        let p = Duration::from_millis(1);
        let mut t = Ticker::new(Instant::from_millis(100), p);
        // Up to one period late: nothing skipped (the deadline is taken late).
        assert_eq!(t.skip_missed(Instant::from_millis(101)), 0);
        assert_eq!(t.next_deadline(), Instant::from_millis(100));
        // 3.5 periods late: skip 3, the next deadline is 0.5 periods past.
        assert_eq!(t.skip_missed(Instant::from_micros(103_500)), 3);
        assert_eq!(t.next_deadline(), Instant::from_millis(103));
        // Before the start: nothing.
        assert_eq!(t.skip_missed(Instant::from_millis(1)), 0);
    }

    #[test]
    fn enter_realtime_reports_either_way() {
        let report = std::thread::spawn(|| {
            enter_realtime(&RtSettings {
                cpu: Some(0),
                ..RtSettings::default()
            })
        })
        .join()
        .unwrap();
        let text = report.to_string();
        // Shown with --nocapture: what this machine granted.
        println!("{text}");
        assert!(text.starts_with("real-time: "));
        if !report.memory_locked {
            assert!(
                report
                    .warnings
                    .iter()
                    .any(|w| w.contains("mlockall") && w.contains("CAP_IPC_LOCK")),
                "{text}"
            );
        }
        match report.fifo_priority {
            Some(p) => assert_eq!(p, 80),
            None => assert!(
                report
                    .warnings
                    .iter()
                    .any(|w| w.contains("os error") && w.contains("CAP_SYS_NICE")),
                "{text}"
            ),
        }
        assert_eq!(report.is_complete(), report.warnings.is_empty());
        assert_eq!(text.lines().count(), 1 + report.warnings.len());
    }

    /// Removes CAP_SYS_NICE and CAP_IPC_LOCK from the calling thread's effective set
    /// (capabilities are per thread on Linux), so the refusals can be seen even as root.
    fn drop_rt_capabilities() {
        #[repr(C)]
        struct Header {
            version: u32,
            pid: libc::c_int,
        }
        #[repr(C)]
        #[derive(Clone, Copy, Default)]
        struct Data {
            effective: u32,
            permitted: u32,
            inheritable: u32,
        }
        const VERSION_3: u32 = 0x2008_0522;
        const CAP_IPC_LOCK: u32 = 14;
        const CAP_SYS_NICE: u32 = 23;
        let mut header = Header {
            version: VERSION_3,
            pid: 0,
        };
        let mut data = [Data::default(); 2];
        // SAFETY: capget fills the two-element data array version 3 asks for.
        let rc = unsafe { libc::syscall(libc::SYS_capget, &mut header, data.as_mut_ptr()) };
        assert_eq!(rc, 0);
        data[0].effective &= !((1 << CAP_IPC_LOCK) | (1 << CAP_SYS_NICE));
        // SAFETY: as above; capset only reads `header` and `data`.
        let rc = unsafe { libc::syscall(libc::SYS_capset, &mut header, data.as_ptr()) };
        assert_eq!(rc, 0);
    }

    #[test]
    fn refusals_name_the_errno_and_the_remedy() {
        let report = std::thread::spawn(|| {
            drop_rt_capabilities();
            enter_realtime(&RtSettings::default())
        })
        .join()
        .unwrap();
        println!("{report}");
        let rtprio = rlimit(libc::RLIMIT_RTPRIO).unwrap_or(0);
        if rtprio < 80 {
            assert_eq!(report.fifo_priority, None);
        }
        if report.fifo_priority.is_none() {
            let w = report
                .warnings
                .iter()
                .find(|w| w.starts_with("SCHED_FIFO priority 80 refused"))
                .unwrap_or_else(|| panic!("{report}"));
            assert!(w.contains("EPERM") && w.contains("ulimit -r"), "{w}");
            assert!(w.contains("CAP_SYS_NICE"), "{w}");
        }
        if !report.memory_locked {
            assert!(
                report
                    .warnings
                    .iter()
                    .any(|w| w.contains("ulimit -l") && w.contains("CAP_IPC_LOCK")),
                "{report}"
            );
        }
        assert!(!report.is_complete() || rtprio >= 80, "{report}");
    }

    #[test]
    fn an_impossible_priority_and_cpu_are_warnings() {
        let report = std::thread::spawn(|| {
            enter_realtime(&RtSettings {
                priority: Some(500),
                cpu: Some(100_000),
                lock_memory: false,
            })
        })
        .join()
        .unwrap();
        assert_eq!(report.fifo_priority, None);
        assert_eq!(report.cpu, None);
        assert!(!report.memory_locked);
        assert_eq!(report.warnings.len(), 2, "{report}");
        assert!(report.warnings[1].contains("CPU 100000"));
    }

    #[test]
    fn sigterm_sets_the_stop_flag() {
        let flag = stop_flag();
        assert!(!flag.load(Ordering::SeqCst));
        // SAFETY: raise sends a signal to this thread; the handler installed above only sets
        // the flag.
        assert_eq!(unsafe { libc::raise(libc::SIGTERM) }, 0);
        assert!(flag.load(Ordering::SeqCst));
        assert!(std::ptr::eq(flag, stop_flag()));
    }

    #[test]
    fn triple_buffer_hands_over_whole_values_under_contention() {
        // Each value is 16 copies of one counter: a torn read would mix two counters.
        const N: u64 = 200_000;
        let (mut w, mut r) = triple_buffer([0u64; 16]);
        let writer = std::thread::spawn(move || {
            for k in 1..=N {
                w.publish([k; 16]);
            }
        });
        let mut last = 0;
        let mut fresh_reads = 0u64;
        loop {
            // Sampled before the read: once the writer has finished, a read must see N.
            let finished = writer.is_finished();
            let (v, fresh) = r.read();
            assert!(v.iter().all(|&x| x == v[0]), "torn: {v:?}");
            assert!(v[0] >= last, "went back from {last} to {}", v[0]);
            if fresh {
                fresh_reads += 1;
            } else {
                assert_eq!(v[0], last, "a changed value must be reported fresh");
            }
            last = v[0];
            if last == N {
                break;
            }
            assert!(!finished, "the last value was never handed over: {last}");
        }
        writer.join().unwrap();
        assert!(fresh_reads >= 1);
        // Nothing new after the last value.
        assert_eq!(r.read(), ([N; 16], false));
    }
}
