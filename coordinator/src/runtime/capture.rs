//! Bus capture off the cycle thread (`coordinator run --capture DIR`): one candump log and one
//! pcap per bus.
//!
//! [`start`] creates `DIR` if needed and, per bus, `DIR/NAME.log` (candump `-l` format,
//! [`drivers::can::candump`]) and `DIR/NAME.pcap` ([`drivers::can::pcap`]), then starts one
//! thread `capture-NAME` per bus. Each thread drains its monitor endpoint every [`POLL`],
//! passes the frames through a [`ReorderBuffer`] (frames of a `vbus:` bus arrive out of
//! timestamp order; on the in-process bus the buffer only delays them) and writes what it
//! releases. [`Capture::stop`] takes what arrived until then, writes everything still held,
//! flushes, joins and reports per bus.
//!
//! Timestamps in the files are the bus's timestamps moved to the Unix epoch (the offset is
//! taken when the thread starts), so other tools show real dates and a capture on a real-clock
//! bus lines up with the wall clock.
//!
//! The monitor endpoints: `VirtualBus::attach_monitor` (the in-process bus, real-clock mode)
//! is `Send` and goes in a [`CaptureBus`]. A `vbus:NAME` endpoint ([`ShmBus`]) is not `Send`
//! (iceoryx2's single-threaded `ipc` service), so it is opened on its capture thread:
//! [`CaptureSource::shm`] with [`start_sources`].
//!
//! The threads use [`Bus::try_recv`] and a short sleep, never [`Bus::recv_until`]: on a
//! virtual-clock port `recv_until` advances the bus's time, which only the simulation may do.
//! A virtual-clock bus can still be captured, but it runs faster than the thread polls: give
//! its ports a receive capacity for the whole run, or expect [`CaptureStats::dropped`].

use drivers::can::candump::CandumpWriter;
use drivers::can::pcap::PcapWriter;
use drivers::can::reorder::ReorderBuffer;
use drivers::can::shm_bus::ShmBus;
use drivers::can::{Bus, Frame};
use drivers::time::Instant;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// How long a capture thread sleeps between drains. A monitor's receive buffer holds hundreds
/// of frames (1024 on the in-process bus by default, 512 on `vbus:`), a fully loaded 1 Mbit/s
/// bus carries about 7 per millisecond.
pub const POLL: Duration = Duration::from_millis(1);

/// How often a capture thread flushes its files while frames keep coming: a run that is
/// killed leaves files complete up to about this long before (minus the reorder window).
pub const FLUSH_EVERY: Duration = Duration::from_millis(100);

/// One bus to capture, with a monitor endpoint already open.
pub struct CaptureBus {
    /// The bus name: the files are `DIR/NAME.log` and `DIR/NAME.pcap`, the candump lines name
    /// it as the interface, the thread is `capture-NAME`.
    pub name: String,
    /// The bus bitrate in bit/s (it sets the reorder window).
    pub bitrate: u32,
    /// A listen-only endpoint that receives every frame on the bus.
    pub monitor: Box<dyn Bus + Send>,
}

/// Opens a monitor endpoint on the capture thread; an error is a sentence for the user.
pub type OpenMonitor = Box<dyn FnOnce() -> Result<Box<dyn Bus>, String> + Send>;

/// One bus to capture, whose monitor endpoint is opened on its capture thread (for endpoints
/// that are not `Send`, such as [`ShmBus`]).
pub struct CaptureSource {
    /// The bus name, as [`CaptureBus::name`].
    pub name: String,
    /// The bus bitrate in bit/s.
    pub bitrate: u32,
    /// Opens the monitor endpoint.
    pub open: OpenMonitor,
}

impl CaptureSource {
    /// The cross-process bus `vbus:NAME`: an [`ShmBus`] endpoint opened on the capture thread.
    /// The files are `NAME.log` and `NAME.pcap`.
    pub fn shm(name: &str, bitrate: u32) -> CaptureSource {
        let bus = name.to_owned();
        CaptureSource {
            name: name.to_owned(),
            bitrate,
            open: Box::new(move || {
                ShmBus::open(&bus, bitrate)
                    .map(|b| Box::new(b) as Box<dyn Bus>)
                    .map_err(|e| e.to_string())
            }),
        }
    }
}

impl From<CaptureBus> for CaptureSource {
    fn from(b: CaptureBus) -> CaptureSource {
        let monitor = b.monitor;
        CaptureSource {
            name: b.name,
            bitrate: b.bitrate,
            open: Box::new(move || Ok(monitor as Box<dyn Bus>)),
        }
    }
}

/// What one capture thread did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CaptureStats {
    /// The bus name.
    pub name: String,
    /// Frames written (to both files).
    pub frames: u64,
    /// Frames written before their reorder window had passed because the buffer was full:
    /// the files may be out of order there.
    pub released_early: u64,
    /// Frames that arrived later than the reorder window allows: written out of order.
    pub late: u64,
    /// Frames the monitor endpoint lost (its receive buffer overflowed).
    pub dropped: u64,
    /// Why the thread stopped early (a write or receive error naming the file or bus).
    pub error: Option<String>,
}

/// The running capture threads; [`Capture::stop`] ends them. Dropping it stops them too, but
/// discards the statistics.
pub struct Capture {
    dir: PathBuf,
    stop: Arc<AtomicBool>,
    threads: Vec<(String, JoinHandle<CaptureStats>)>,
}

impl core::fmt::Debug for Capture {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Capture")
            .field("dir", &self.dir)
            .field("buses", &self.threads.len())
            .finish()
    }
}

impl Capture {
    /// The directory the files are written to.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Stops every thread after it has taken what its monitor received so far, writes every
    /// frame still held, flushes and closes the files. One entry per bus, in the order given
    /// to [`start`].
    pub fn stop(mut self) -> Vec<CaptureStats> {
        self.join()
    }

    fn join(&mut self) -> Vec<CaptureStats> {
        self.stop.store(true, Ordering::Release);
        self.threads
            .drain(..)
            .map(|(name, t)| {
                t.join().unwrap_or_else(|_| CaptureStats {
                    error: Some(format!("the capture thread of bus {name} panicked")),
                    name,
                    frames: 0,
                    released_early: 0,
                    late: 0,
                    dropped: 0,
                })
            })
            .collect()
    }
}

impl Drop for Capture {
    fn drop(&mut self) {
        self.join();
    }
}

/// Starts capturing `buses` into `dir`; see the module docs.
pub fn start(dir: &Path, buses: Vec<CaptureBus>) -> Result<Capture, String> {
    start_sources(dir, buses.into_iter().map(CaptureSource::from).collect())
}

/// As [`start`], for monitors opened on their capture threads. Returns once every monitor is
/// open (a `vbus:` frame sent before its receiver opened is lost), or with the first error
/// (the threads already started are stopped).
pub fn start_sources(dir: &Path, sources: Vec<CaptureSource>) -> Result<Capture, String> {
    for (i, s) in sources.iter().enumerate() {
        check_name(&s.name)?;
        if sources[..i].iter().any(|o| o.name == s.name) {
            return Err(format!("bus {} is captured twice", s.name));
        }
    }
    std::fs::create_dir_all(dir)
        .map_err(|e| format!("cannot create capture directory {}: {e}", dir.display()))?;
    // All files first: a bad directory fails before any thread runs.
    let mut writers = Vec::with_capacity(sources.len());
    for s in &sources {
        writers.push(Writer::create(dir, &s.name)?);
    }
    let mut capture = Capture {
        dir: dir.to_owned(),
        stop: Arc::new(AtomicBool::new(false)),
        threads: Vec::with_capacity(sources.len()),
    };
    for (source, writer) in sources.into_iter().zip(writers) {
        let (ready_tx, ready_rx) = mpsc::channel();
        let stop = capture.stop.clone();
        let CaptureSource {
            name,
            bitrate,
            open,
        } = source;
        let thread = std::thread::Builder::new()
            .name(format!("capture-{name}"))
            .spawn(move || {
                let bus = match open() {
                    Ok(b) => {
                        let _ = ready_tx.send(Ok(()));
                        b
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return writer.stats(None, None);
                    }
                };
                run(bus, writer, bitrate, &stop)
            })
            .map_err(|e| format!("cannot start the capture thread of bus {name}: {e}"))?;
        capture.threads.push((name.clone(), thread));
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(format!("capturing bus {name}: {e}")),
            Err(_) => return Err(format!("the capture thread of bus {name} ended at start")),
        }
    }
    Ok(capture)
}

/// Virtual time's capture: the same files, written inline as the virtual buses deliver their
/// frames (already in timestamp order), with the buses' own timestamps (virtual time starts at
/// zero).
pub struct InlineCapture {
    writers: Vec<Writer>,
    error: Option<String>,
}

impl std::fmt::Debug for InlineCapture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("InlineCapture").finish_non_exhaustive()
    }
}

impl InlineCapture {
    /// Creates `DIR/NAME.log` and `DIR/NAME.pcap` for every bus name, in bus order.
    pub fn create(dir: &Path, names: &[String]) -> Result<InlineCapture, String> {
        for (i, n) in names.iter().enumerate() {
            check_name(n)?;
            if names[..i].contains(n) {
                return Err(format!("bus {n} is captured twice"));
            }
        }
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("cannot create capture directory {}: {e}", dir.display()))?;
        let mut writers = Vec::with_capacity(names.len());
        for n in names {
            writers.push(Writer::create(dir, n)?);
        }
        Ok(InlineCapture {
            writers,
            error: None,
        })
    }

    /// Writes one frame of bus `bus` (the first write error is kept for [`InlineCapture::finish`]).
    pub fn write(&mut self, bus: usize, frame: &Frame) {
        if self.error.is_some() {
            return;
        }
        if let Some(w) = self.writers.get_mut(bus)
            && let Err(e) = w.write(frame)
        {
            self.error = Some(e);
        }
    }

    /// Flushes and closes the files.
    pub fn finish(self) -> Vec<CaptureStats> {
        let mut error = self.error;
        self.writers
            .into_iter()
            .map(|mut w| {
                if let Err(e) = w.flush() {
                    error.get_or_insert(e);
                }
                let mut s = w.stats(None, None);
                s.error = error.clone();
                s
            })
            .collect()
    }
}

/// A bus name becomes a file name: no separators, nothing that names a directory.
fn check_name(name: &str) -> Result<(), String> {
    if name.is_empty() || name == "." || name == ".." || name.contains(['/', '\0']) {
        return Err(format!(
            "cannot capture bus `{name}`: the name must be usable as a file name"
        ));
    }
    Ok(())
}

/// One bus's two files.
struct Writer {
    name: String,
    log_path: PathBuf,
    pcap_path: PathBuf,
    log: CandumpWriter<BufWriter<File>>,
    pcap: PcapWriter<BufWriter<File>>,
    /// Added to bus timestamps to give Unix time.
    offset: u64,
    frames: u64,
    unflushed: bool,
}

impl Writer {
    fn create(dir: &Path, name: &str) -> Result<Writer, String> {
        let log_path = dir.join(format!("{name}.log"));
        let pcap_path = dir.join(format!("{name}.pcap"));
        let open = |p: &Path| {
            File::create(p)
                .map(BufWriter::new)
                .map_err(|e| format!("cannot create {}: {e}", p.display()))
        };
        let log = CandumpWriter::new(open(&log_path)?);
        let pcap = PcapWriter::new(open(&pcap_path)?)
            .map_err(|e| format!("writing {}: {e}", pcap_path.display()))?;
        Ok(Writer {
            name: name.to_owned(),
            log_path,
            pcap_path,
            log,
            pcap,
            offset: 0,
            frames: 0,
            unflushed: false,
        })
    }

    fn write(&mut self, frame: &Frame) -> Result<(), String> {
        let wall = Instant::from_nanos(frame.timestamp().as_nanos().saturating_add(self.offset));
        self.log
            .write(wall, &self.name, frame)
            .map_err(|e| format!("writing {}: {e}", self.log_path.display()))?;
        self.pcap
            .write(wall, frame)
            .map_err(|e| format!("writing {}: {e}", self.pcap_path.display()))?;
        self.frames += 1;
        self.unflushed = true;
        Ok(())
    }

    fn flush(&mut self) -> Result<(), String> {
        self.log
            .flush()
            .map_err(|e| format!("writing {}: {e}", self.log_path.display()))?;
        self.pcap
            .flush()
            .map_err(|e| format!("writing {}: {e}", self.pcap_path.display()))?;
        self.unflushed = false;
        Ok(())
    }

    fn stats(self, reorder: Option<&ReorderBuffer>, bus: Option<&dyn Bus>) -> CaptureStats {
        CaptureStats {
            name: self.name,
            frames: self.frames,
            released_early: reorder.map_or(0, |r| r.released_early()),
            late: reorder.map_or(0, |r| r.late()),
            dropped: bus.map_or(0, |b| b.counters().dropped),
            error: None,
        }
    }
}

/// The capture thread: drain, reorder, write, until `stop`; then write what is held.
fn run(mut bus: Box<dyn Bus>, mut writer: Writer, bitrate: u32, stop: &AtomicBool) -> CaptureStats {
    let wall = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
    writer.offset = wall.saturating_sub(bus.now().as_nanos());
    let mut reorder = ReorderBuffer::for_shm_bus(bitrate);
    let result = pump(bus.as_mut(), &mut writer, &mut reorder, stop).and_then(|()| {
        std::iter::from_fn(|| reorder.pop_oldest()).try_for_each(|f| writer.write(&f))?;
        writer.flush()
    });
    let mut stats = writer.stats(Some(&reorder), Some(bus.as_ref()));
    stats.error = result.err();
    stats
}

fn pump(
    bus: &mut dyn Bus,
    writer: &mut Writer,
    reorder: &mut ReorderBuffer,
    stop: &AtomicBool,
) -> Result<(), String> {
    let mut last_flush = bus.now();
    loop {
        // Read before draining: frames that arrived before `stop` was set are still taken.
        let stopping = stop.load(Ordering::Acquire);
        while let Some(f) = bus
            .try_recv()
            .map_err(|e| format!("receiving on bus {}: {e}", writer.name))?
        {
            if let Some(early) = reorder.push(f) {
                writer.write(&early)?;
            }
        }
        if stopping {
            return Ok(());
        }
        let now = bus.now();
        while let Some(f) = reorder.pop_ready(now) {
            writer.write(&f)?;
        }
        if writer.unflushed && now - last_flush >= FLUSH_EVERY {
            writer.flush()?;
            last_flush = now;
        }
        std::thread::sleep(POLL);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use drivers::can::candump::{LogRecord, read_log};
    use drivers::can::pcap::read_pcap;
    use drivers::can::{BusError, ClockMode, VirtualBus, VirtualBusConfig};
    use std::io::BufReader;
    use std::sync::atomic::AtomicU32;

    fn unique(tag: &str) -> String {
        static N: AtomicU32 = AtomicU32::new(0);
        format!(
            "capture-{tag}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        )
    }

    /// A directory under the temp dir, removed when the test ends.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new(tag: &str) -> TempDir {
            TempDir(std::env::temp_dir().join(unique(tag)))
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    fn read_back(dir: &Path, name: &str) -> (Vec<LogRecord>, Vec<(Instant, Frame)>) {
        let log = File::open(dir.join(format!("{name}.log"))).unwrap();
        let log = read_log(BufReader::new(log)).unwrap();
        let pcap = read_pcap(&std::fs::read(dir.join(format!("{name}.pcap"))).unwrap()).unwrap();
        (log, pcap)
    }

    /// Non-decreasing timestamps, every (sender id, index) once, each sender's frames in order.
    fn check_complete_and_ordered(log: &[LogRecord], senders: u16, per_sender: u16) {
        for (k, w) in log.windows(2).enumerate() {
            assert!(
                w[1].timestamp >= w[0].timestamp,
                "line {}: {} after {}",
                k + 2,
                w[1].timestamp,
                w[0].timestamp
            );
        }
        assert_eq!(log.len(), usize::from(senders * per_sender));
        for s in 0..senders {
            let seq: Vec<u16> = log
                .iter()
                .filter(|r| r.frame.raw_id() == u32::from(0x180 + s))
                .map(|r| u16::from_be_bytes([r.frame.data()[0], r.frame.data()[1]]))
                .collect();
            assert_eq!(seq, (0..per_sender).collect::<Vec<_>>(), "sender {s}");
        }
    }

    fn send_retrying(bus: &mut dyn Bus, f: &Frame) {
        loop {
            match bus.send(f) {
                Ok(()) => return,
                Err(BusError::WouldBlock) => std::thread::sleep(Duration::from_micros(200)),
                Err(e) => panic!("sending {f}: {e}"),
            }
        }
    }

    fn frame(sender: u16, k: u16) -> Frame {
        Frame::new_std(0x180 + sender, &k.to_be_bytes()).unwrap()
    }

    #[test]
    fn the_in_process_monitor_is_send() {
        fn assert_send<T: Send>() {}
        assert_send::<drivers::can::VirtualPort>();
    }

    #[test]
    fn captures_two_senders_on_a_real_clock_virtual_bus() {
        const PER_SENDER: u16 = 150;
        let dir = TempDir::new("vbus");
        let bus = VirtualBus::new(VirtualBusConfig {
            clock: ClockMode::Real,
            ..VirtualBusConfig::default()
        })
        .unwrap();
        let capture = start(
            &dir.0.join("sub"),
            vec![CaptureBus {
                name: "main".into(),
                bitrate: bus.config().bitrate,
                monitor: Box::new(bus.attach_monitor("capture")),
            }],
        )
        .unwrap();
        assert_eq!(capture.dir(), dir.0.join("sub"));
        let senders: Vec<_> = (0..2)
            .map(|s| {
                let mut port = bus.attach(&format!("node{s}"));
                std::thread::spawn(move || {
                    for k in 0..PER_SENDER {
                        send_retrying(&mut port, &frame(s, k));
                    }
                    port
                })
            })
            .collect();
        // Keep the ports attached until their frames have left the wire.
        let _ports: Vec<_> = senders.into_iter().map(|t| t.join().unwrap()).collect();
        bus.run_until_idle();
        let stats = capture.stop();

        assert_eq!(
            stats,
            [CaptureStats {
                name: "main".into(),
                frames: 2 * u64::from(PER_SENDER),
                released_early: 0,
                late: 0,
                dropped: 0,
                error: None,
            }]
        );
        let (log, pcap) = read_back(&dir.0.join("sub"), "main");
        check_complete_and_ordered(&log, 2, PER_SENDER);
        assert!(log.iter().all(|r| r.interface == "main"));
        // The pcap holds the same frames, in the same order, at the same times.
        assert_eq!(pcap.len(), log.len());
        for (r, (t, f)) in log.iter().zip(&pcap) {
            assert_eq!((r.timestamp, r.frame), (*t, *f));
        }
    }

    #[test]
    fn a_vbus_monitor_opened_on_its_thread_writes_several_senders_in_order() {
        // As in drivers/tests/canbus_dump_order.rs: bursts whose modelled backlogs overlap, so
        // frames arrive out of timestamp order.
        const SENDERS: u16 = 3;
        const BURST: u16 = 60;
        const BITRATE: u32 = 125_000;
        let dir = TempDir::new("shm");
        let bus = unique("bus");
        let capture = start_sources(&dir.0, vec![CaptureSource::shm(&bus, BITRATE)]).unwrap();
        let (sent_tx, sent_rx) = mpsc::channel();
        let (release_tx, release_rx) = mpsc::channel::<()>();
        let release_rx = Arc::new(std::sync::Mutex::new(release_rx));
        let threads: Vec<_> = (0..SENDERS)
            .map(|s| {
                let (bus, sent_tx, release_rx) = (bus.clone(), sent_tx.clone(), release_rx.clone());
                std::thread::spawn(move || {
                    let mut tx = ShmBus::open(&bus, BITRATE).unwrap();
                    for k in 0..BURST {
                        send_retrying(&mut tx, &frame(s, k));
                    }
                    sent_tx.send(()).unwrap();
                    // A vbus frame lives in its sender's memory: stay until the capture stopped.
                    let _ = release_rx.lock().unwrap().recv();
                })
            })
            .collect();
        for _ in 0..SENDERS {
            sent_rx.recv_timeout(Duration::from_secs(10)).unwrap();
        }
        // Stop while the thread has released part of the frames (the window is about 130 ms,
        // the bursts' timestamps span about 65 ms): both paths write, in one order.
        std::thread::sleep(Duration::from_millis(150));
        let stats = capture.stop();
        drop(release_tx);
        for t in threads {
            t.join().unwrap();
        }
        assert_eq!(stats.len(), 1);
        assert_eq!(stats[0].error, None);
        assert_eq!(stats[0].frames, u64::from(SENDERS * BURST));
        assert_eq!((stats[0].released_early, stats[0].late), (0, 0));
        let (log, pcap) = read_back(&dir.0, &bus);
        check_complete_and_ordered(&log, SENDERS, BURST);
        assert_eq!(pcap.len(), log.len());
    }

    #[test]
    fn errors_name_the_file_or_the_bus() {
        let dir = TempDir::new("err");
        std::fs::create_dir_all(&dir.0).unwrap();
        // A directory where the log file should go.
        std::fs::create_dir(dir.0.join("main.log")).unwrap();
        let bus = VirtualBus::new(VirtualBusConfig::default()).unwrap();
        let monitor = |name: &str| CaptureBus {
            name: name.into(),
            bitrate: 1_000_000,
            monitor: Box::new(bus.attach_monitor("capture")),
        };
        let e = start(&dir.0, vec![monitor("main")]).unwrap_err();
        assert!(
            e.contains(&dir.0.join("main.log").display().to_string()),
            "{e}"
        );
        assert!(e.contains("os error"), "{e}");

        // The directory itself cannot be created under a regular file.
        let file = dir.0.join("plain");
        std::fs::write(&file, b"").unwrap();
        let e = start(&file.join("sub"), vec![monitor("a")]).unwrap_err();
        assert!(e.contains(&file.join("sub").display().to_string()), "{e}");
        assert!(e.contains("os error"), "{e}");

        let e = start(&dir.0, vec![monitor("x/y")]).unwrap_err();
        assert!(e.contains("`x/y`"), "{e}");
        let e = start(&dir.0, vec![monitor("a"), monitor("a")]).unwrap_err();
        assert!(e.contains("twice"), "{e}");

        // A monitor that cannot be opened: its message, and the bus it belongs to.
        let failing = CaptureSource {
            name: "later".into(),
            bitrate: 1_000_000,
            open: Box::new(|| Err("no such bus".into())),
        };
        let e = start_sources(&dir.0, vec![monitor("first").into(), failing]).unwrap_err();
        assert_eq!(e, "capturing bus later: no such bus");
        // A vbus bitrate out of range is reported by the endpoint.
        let e = start_sources(&dir.0, vec![CaptureSource::shm(&unique("rate"), 1)]).unwrap_err();
        assert!(e.contains("bitrate 1 bit/s"), "{e}");
    }
}
