//! The CMMO-ST Modbus server on a real TCP socket: one std thread runs the listener, the one
//! connection, the device's time and the node guard in a single loop.
//!
//! Why a thread and not an async runtime: the device has exactly one connection, so there is
//! nothing to multiplex, and a single loop keeps the order of events (step the device, accept,
//! guard, read, answer) explicit. The loop wakes at least every [`ServerConfig::tick`]: the
//! read timeout bounds the wait, and a listener in non-blocking mode is polled for a second
//! client, which is closed at once.
//!
//! Why not `tokio-modbus` (0.17.0, evaluated from its sources): its server decoder turns a
//! byte count that does not match the quantity, an unknown MEI type, a bad device-id code or a
//! function code of 0x80 and above into an I/O error and drops the connection, where the
//! CMMO-ST answers with exception 0x03 or 0x01; and its `serve` spawns each connection's task
//! internally, so a silent client cannot be closed when the node guard expires. It also
//! allocates per request. The wire format here is small ([`super::mbap`]) and allocation-free.
//!
//! Time: the device sees [`Instant`]s counted from [`ServerConfig::epoch`] on the monotonic
//! clock, so several simulated drives can share one time base.

use std::io::{self, ErrorKind, Read, Write};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::{self, JoinHandle};
use std::time::Duration;

use super::mbap::{Deframer, MAX_ADU};
use super::session::{Session, Stats};
use super::{Config, ConfigError, FhppDevice};
use crate::time::Instant;

/// Where and how the server runs.
#[derive(Debug, Clone, Copy)]
pub struct ServerConfig {
    /// The address to bind. Port 0 lets the OS choose; [`Server::local_addr`] reports it.
    pub addr: SocketAddr,
    /// Profile and node-guard timeout.
    pub modbus: Config,
    /// The longest the loop waits before stepping the device and looking for a new client.
    /// The digest suggests 2 ms for FHPP input sampling (§8).
    pub tick: Duration,
    /// The instant the device's time counts from.
    pub epoch: std::time::Instant,
}

impl ServerConfig {
    /// 127.0.0.1 on `port`, factory interface settings, a 2 ms tick, time counted from now.
    pub fn loopback(port: u16) -> ServerConfig {
        ServerConfig {
            addr: SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, port)),
            modbus: Config::default(),
            tick: Duration::from_millis(2),
            epoch: std::time::Instant::now(),
        }
    }
}

/// What the server thread publishes after each loop.
#[derive(Debug, Clone, Copy, Default)]
struct Shared {
    stats: Stats,
    connected: bool,
}

/// A running CMMO-ST Modbus TCP server. Dropping it stops the thread.
#[derive(Debug)]
pub struct Server {
    local_addr: SocketAddr,
    stop: Arc<AtomicBool>,
    shared: Arc<Mutex<Shared>>,
    thread: Option<JoinHandle<()>>,
}

/// Why the server could not start.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    /// Binding or configuring the listener failed.
    #[error("cannot listen on {addr}: {source}")]
    Listen {
        /// The address asked for.
        addr: SocketAddr,
        /// The OS error.
        source: io::Error,
    },
    /// The interface configuration is one the device would refuse.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The thread could not be started.
    #[error("cannot start the server thread: {0}")]
    Thread(io::Error),
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic elsewhere while holding the device must not take the server down with it.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Server {
    /// Binds `config.addr` and serves `device` on a new thread.
    ///
    /// ```
    /// use std::io::{Read, Write};
    /// use std::sync::{Arc, Mutex};
    /// use drivers::sim::cmmo_st::{FhppDevice, Identification, Server, ServerConfig};
    /// use drivers::time::Instant;
    ///
    /// struct PowerOn; // a stand-in device: the power-on status image, nothing more
    /// impl FhppDevice for PowerOn {
    ///     fn exchange(&mut self, _o: &[u8; 8], _t: Instant) -> [u8; 8] { [0x10, 0x04, 0, 0, 0, 0, 0, 0] }
    ///     fn parameter(&mut self, _r: &[u8; 8], _t: Instant) -> [u8; 8] { [0; 8] }
    ///     fn step_to(&mut self, _t: Instant) {}
    ///     fn fault_number(&self) -> u16 { 0 }
    ///     fn identification(&self) -> Identification<'_> { Identification::default() }
    ///     fn master_control(&self) -> bool { true }
    /// }
    ///
    /// let server = Server::spawn(ServerConfig::loopback(0), Arc::new(Mutex::new(PowerOn))).unwrap();
    /// let mut client = std::net::TcpStream::connect(server.local_addr()).unwrap();
    /// client.write_all(&[0, 1, 0, 0, 0, 6, 0, 0x03, 0, 0, 0, 4]).unwrap();
    /// let mut resp = [0; 17];
    /// client.read_exact(&mut resp).unwrap();
    /// assert_eq!(resp[7..11], [0x03, 8, 0x10, 0x04]);
    /// ```
    pub fn spawn<D: FhppDevice + Send + 'static>(
        config: ServerConfig,
        device: Arc<Mutex<D>>,
    ) -> Result<Server, StartError> {
        let session = Session::new(config.modbus)?;
        let listen_err = |source| StartError::Listen {
            addr: config.addr,
            source,
        };
        let listener = TcpListener::bind(config.addr).map_err(listen_err)?;
        listener.set_nonblocking(true).map_err(listen_err)?;
        let local_addr = listener.local_addr().map_err(listen_err)?;
        let stop = Arc::new(AtomicBool::new(false));
        let shared = Arc::new(Mutex::new(Shared::default()));
        let mut worker = Worker {
            listener,
            conn: None,
            deframer: Deframer::new(),
            session,
            device,
            config,
            stop: Arc::clone(&stop),
            shared: Arc::clone(&shared),
        };
        let thread = thread::Builder::new()
            .name(format!("cmmo-st-modbus-{}", local_addr.port()))
            .spawn(move || worker.run())
            .map_err(StartError::Thread)?;
        Ok(Server {
            local_addr,
            stop,
            shared,
            thread: Some(thread),
        })
    }

    /// The address actually bound (with the OS-chosen port).
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// Counters as of the end of the server's last loop.
    pub fn stats(&self) -> Stats {
        lock(&self.shared).stats
    }

    /// Whether a client is connected, as of the end of the server's last loop.
    pub fn is_connected(&self) -> bool {
        lock(&self.shared).connected
    }

    /// Stops the thread (within one tick) and waits for it; closes the connection.
    pub fn shutdown(mut self) -> Stats {
        self.stop_and_join();
        self.stats()
    }

    fn stop_and_join(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            // A panicked server thread has nothing left to clean up.
            let _ = t.join();
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop_and_join();
    }
}

struct Worker<D> {
    listener: TcpListener,
    conn: Option<TcpStream>,
    deframer: Deframer,
    session: Session,
    device: Arc<Mutex<D>>,
    config: ServerConfig,
    stop: Arc<AtomicBool>,
    shared: Arc<Mutex<Shared>>,
}

impl<D: FhppDevice> Worker<D> {
    fn now(&self) -> Instant {
        let ns = self.config.epoch.elapsed().as_nanos();
        Instant::from_nanos(u64::try_from(ns).unwrap_or(u64::MAX))
    }

    fn run(&mut self) {
        while !self.stop.load(Ordering::Relaxed) {
            let now = self.now();
            lock(&self.device).step_to(now);
            self.accept(now);
            if self.session.poll_timeout().is_some_and(|d| now >= d) {
                let lost = self.session.handle_timeout(&mut *lock(&self.device), now);
                if lost.is_some() {
                    self.close();
                }
            }
            self.wait_and_serve(now);
            self.publish();
        }
        self.close();
    }

    /// Makes the counters visible to [`Server`]. Called before every effect a client can see
    /// (a response, a close), so what a client observed is already counted.
    fn publish(&self) {
        let mut shared = lock(&self.shared);
        shared.stats = self.session.stats();
        shared.connected = self.session.is_connected();
    }

    /// Takes every pending connection: the first becomes the client, any other is closed
    /// unanswered (one Modbus connection at a time, §4).
    fn accept(&mut self, now: Instant) {
        loop {
            match self.listener.accept() {
                Ok((stream, _peer)) => {
                    let admitted = self.session.connect(&mut *lock(&self.device), now);
                    if admitted && Self::configure(&stream).is_ok() {
                        self.deframer.clear();
                        self.conn = Some(stream);
                    } else if admitted {
                        self.session.disconnect();
                    }
                    self.publish();
                    // A refused stream is dropped here, which closes it.
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                // WouldBlock: nobody waiting. Anything else (e.g. out of descriptors) is
                // transient for a listener; try again next tick.
                Err(_) => break,
            }
        }
    }

    fn configure(stream: &TcpStream) -> io::Result<()> {
        stream.set_nonblocking(false)?;
        // Responses are small and latency matters more than packing.
        stream.set_nodelay(true)?;
        // A client that stops reading must not stall the device's time.
        stream.set_write_timeout(Some(Duration::from_secs(1)))
    }

    fn close(&mut self) {
        self.session.disconnect();
        self.publish();
        self.deframer.clear();
        // Dropping the stream closes it.
        self.conn = None;
    }

    /// Waits up to one tick (less if the node guard expires sooner) for request bytes, and
    /// answers every whole frame that arrived.
    fn wait_and_serve(&mut self, now: Instant) {
        let mut wait = self.config.tick;
        if let Some(deadline) = self.session.poll_timeout() {
            wait = wait.min(deadline.saturating_duration_since(now));
        }
        // A zero read timeout is an error on std; wait at least a little.
        let wait = wait.max(Duration::from_micros(100));
        let Some(stream) = self.conn.as_mut() else {
            thread::sleep(wait);
            return;
        };
        let mut buf = [0u8; MAX_ADU];
        let room = self.deframer.space().min(buf.len());
        let read = stream
            .set_read_timeout(Some(wait))
            .and_then(|()| stream.read(buf.get_mut(..room).unwrap_or(&mut [])));
        match read {
            Ok(0) => self.close(),
            Ok(n) => {
                self.deframer.push(buf.get(..n).unwrap_or(&[]));
                if self.serve_frames().is_err() {
                    self.close();
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                ) => {}
            Err(_) => self.close(),
        }
    }

    /// Answers the frames in the deframer, in order. `Err`: close the connection (a frame the
    /// stream cannot be resynchronised after, or a failed write).
    fn serve_frames(&mut self) -> Result<(), ()> {
        let mut adu = [0u8; MAX_ADU];
        let mut out = [0u8; MAX_ADU];
        loop {
            let len = match self.deframer.next_frame(&mut adu) {
                Ok(Some(len)) => len,
                Ok(None) => return Ok(()),
                Err(_) => return Err(()),
            };
            let now = self.now();
            let frame = adu.get(..len).unwrap_or(&[]);
            let reply = self
                .session
                .handle_frame(frame, &mut *lock(&self.device), now, &mut out)
                .map_err(|_| ())?;
            self.publish();
            if let (Some(n), Some(stream)) = (reply, self.conn.as_mut()) {
                stream
                    .write_all(out.get(..n).unwrap_or(&[]))
                    .map_err(|_| ())?;
            }
        }
    }
}
