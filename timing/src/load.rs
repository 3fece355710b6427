//! `--load`: a documented background load for the length of a run, so a figure can be taken on
//! a busy machine on purpose rather than by accident.
//!
//! What it is, exactly (all threads of this process, on the normal scheduler, nice 0):
//! - one **busy thread per CPU** this process may use: integer arithmetic in a loop, no
//!   system calls, no memory beyond its stack;
//! - one **churner** thread that, in a loop: allocates a 16 MiB buffer and writes one byte per
//!   4 KiB page (the allocator maps it fresh: mmap plus 4096 page faults), frees it (munmap),
//!   writes 64 KiB to `/dev/null` in 4 KiB writes, and yields (`sched_yield`).
//!
//! A SCHED_FIFO measuring thread preempts all of them; what it still sees is what a busy
//! machine costs through the kernel (page-table work, TLB shoot-downs, interrupts, caches).

use std::io::Write as _;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;

/// The load's description, as `summary.json` and the table print it.
pub const DESCRIPTION: &str = "one busy thread per CPU (integer arithmetic, nice 0) and one churner (16 MiB allocated, touched per page and freed, 64 KiB written to /dev/null, sched_yield, in a loop)";

/// A running background load; stops when dropped.
#[derive(Debug)]
pub struct Load {
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    /// Rounds the churner completed (shows the load ran).
    pub churn_rounds: Arc<AtomicU64>,
}

impl Load {
    /// Starts the load.
    pub fn start() -> Load {
        let stop = Arc::new(AtomicBool::new(false));
        let churn_rounds = Arc::new(AtomicU64::new(0));
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let mut threads = Vec::with_capacity(cpus + 1);
        for i in 0..cpus {
            let stop = stop.clone();
            if let Ok(t) = std::thread::Builder::new()
                .name(format!("load-busy-{i}"))
                .spawn(move || busy(&stop))
            {
                threads.push(t);
            }
        }
        let s = stop.clone();
        let rounds = churn_rounds.clone();
        if let Ok(t) = std::thread::Builder::new()
            .name("load-churn".into())
            .spawn(move || churn(&s, &rounds))
        {
            threads.push(t);
        }
        Load {
            stop,
            threads,
            churn_rounds,
        }
    }
}

impl Drop for Load {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

fn busy(stop: &AtomicBool) {
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    while !stop.load(Ordering::Relaxed) {
        for _ in 0..10_000 {
            // xorshift: work the optimiser cannot drop.
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
        }
        std::hint::black_box(x);
    }
}

fn churn(stop: &AtomicBool, rounds: &AtomicU64) {
    const BUFFER: usize = 16 << 20;
    let mut null = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/null")
        .ok();
    let block = [0u8; 4096];
    while !stop.load(Ordering::Relaxed) {
        let mut v = vec![0u8; BUFFER];
        for b in v.iter_mut().step_by(4096) {
            *b = 1;
        }
        std::hint::black_box(&mut v);
        drop(v);
        if let Some(f) = &mut null {
            for _ in 0..16 {
                let _ = f.write_all(&block);
            }
        }
        std::thread::yield_now();
        rounds.fetch_add(1, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_load_runs_and_stops() {
        let load = Load::start();
        let rounds = load.churn_rounds.clone();
        let t0 = std::time::Instant::now();
        while rounds.load(Ordering::Relaxed) == 0 && t0.elapsed().as_secs() < 30 {
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert!(rounds.load(Ordering::Relaxed) > 0);
        drop(load);
    }
}
