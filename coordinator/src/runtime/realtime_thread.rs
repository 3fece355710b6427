//! What makes a thread the real-time cycle thread, as far as the system allows:
//! [`enter_realtime`] locks memory, switches to SCHED_FIFO and pins a CPU; [`leave_realtime`]
//! gives it back.
//!
//! Nothing here fails hard when the system refuses real-time privileges: the coordinator must
//! still run (slower, with jitter) on a developer machine, and say clearly what was refused and
//! how to grant it. `unsafe` appears only around libc calls, each with its `SAFETY` argument.

use std::fmt;
use std::io;

/// What [`enter_realtime`] asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RealtimeSettings {
    /// SCHED_FIFO priority (1..=99; 80 by default: above the kernel's threaded IRQ handlers at
    /// 50, below the watchdogs at 99). `None`: stay on the normal scheduler.
    pub priority: Option<i32>,
    /// Pin the calling thread to this CPU.
    pub cpu: Option<usize>,
    /// `mlockall(MCL_CURRENT | MCL_FUTURE)` and touch some stack, so no page fault hits the
    /// cycle.
    pub lock_memory: bool,
}

impl Default for RealtimeSettings {
    fn default() -> Self {
        RealtimeSettings {
            priority: Some(80),
            cpu: None,
            lock_memory: true,
        }
    }
}

/// What [`enter_realtime`] obtained. `Display` prints one line of what was granted, then one
/// line per warning.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RealtimeReport {
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

impl RealtimeReport {
    /// Everything asked for was granted.
    pub fn is_complete(&self) -> bool {
        self.warnings.is_empty()
    }
}

impl fmt::Display for RealtimeReport {
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
pub fn enter_realtime(settings: &RealtimeSettings) -> RealtimeReport {
    let mut report = RealtimeReport::default();
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn enter_realtime_reports_either_way() {
        let report = std::thread::spawn(|| {
            enter_realtime(&RealtimeSettings {
                cpu: Some(0),
                ..RealtimeSettings::default()
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
            enter_realtime(&RealtimeSettings::default())
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
            enter_realtime(&RealtimeSettings {
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
}
