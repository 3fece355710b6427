//! The CMMO-ST's cyclic Modbus TCP exchange, run on its own thread so the cycle thread never
//! touches a socket.
//!
//! [`spawn`] starts the exchange thread and returns the [`ModbusCycleSide`] the cycle thread
//! uses: [`put_output`](ModbusCycleSide::put_output) hands over this cycle's 8 control bytes,
//! [`take_input`](ModbusCycleSide::take_input) the latest status bytes with their age and the
//! link state. Both are two triple-buffer operations ([`handover::triple_buffer::triple_buffer`]): no lock,
//! no allocation, no syscall.
//!
//! The exchange thread:
//! - connects (TCP_NODELAY), and on any failure reconnects with exponential back-off;
//! - sends one FC 0x17 per new output image (it polls for one every `settings.poll`), and
//!   re-sends the last image when no new one came for a whole `period`, so the device's node
//!   guard stays fed while the cycle is not running yet;
//! - has one request outstanding at a time: an image put while waiting is sent after the
//!   answer (the latest one wins, none is queued);
//! - publishes every answer, tagged with the cycle of the output it answered;
//! - gives up on an answer after `settings.timeout`: the link is [`Link::TimedOut`], the
//!   connection is closed and opened again (a stream whose answer went missing is not trusted).
//!
//! Lateness is never waited for, only reported: an answer to the output of cycle `n` is on
//! time when it is taken in cycle `n + 1` (one cycle of latency is inherent in an exchange off
//! the cycle thread); [`ModbusInput::late_cycles`] counts the cycles beyond that.

use std::io::{self, ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::{self, JoinHandle};
use std::time::Duration;

use drivers::modbus::client::{self, Client, MAX_ADU, ResponseError};
use drivers::time::{Instant, monotonic_now};

use handover::triple_buffer::{TripleReader, TripleWriter, triple_buffer};

/// How the exchange thread runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModbusSettings {
    /// The cycle period: the longest the thread goes without sending (it sends the last image
    /// again when no new one came).
    pub period: Duration,
    /// How often the thread looks for a new output image while idle (a shorter poll sends
    /// sooner after `put_output`, at the cost of more wake-ups).
    pub poll: Duration,
    /// No answer this long after a request: [`Link::TimedOut`], reconnect. Keep it below the
    /// device's node-guard timeout (the digest suggests period ≤ node guard / 3).
    pub timeout: Duration,
    /// The longest one connection attempt may take.
    pub connect_timeout: Duration,
    /// The first wait before reconnecting; doubled after each failure up to `backoff_max`, back
    /// to this after an answer.
    pub backoff_min: Duration,
    /// The longest wait between connection attempts.
    pub backoff_max: Duration,
    /// The MBAP unit id (the CMMO-ST ignores it and echoes it).
    pub unit_id: u8,
}

impl Default for ModbusSettings {
    /// A 10 ms cycle, 250 µs poll, 50 ms answer timeout (below the CMMO-ST's 100 ms minimum
    /// node guard), back-off 20 ms .. 1 s.
    fn default() -> Self {
        ModbusSettings {
            period: Duration::from_millis(10),
            poll: Duration::from_micros(250),
            timeout: Duration::from_millis(50),
            connect_timeout: Duration::from_millis(200),
            backoff_min: Duration::from_millis(20),
            backoff_max: Duration::from_secs(1),
            unit_id: 0,
        }
    }
}

/// Why the link is down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DownReason {
    /// Connecting failed (refused, unreachable, timed out).
    #[error("cannot connect: {0}")]
    Connect(ErrorKind),
    /// The device closed the connection.
    #[error("connection closed by the device")]
    Closed,
    /// Reading or writing the socket failed.
    #[error("socket error: {0}")]
    Io(ErrorKind),
    /// The device answered with an exception or with a frame that is not the answer asked
    /// for. An exception keeps the connection; a malformed frame closes it.
    #[error("bad answer: {0}")]
    Response(ResponseError),
}

/// The state of the connection to the device, as of the last answer or failure.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Link {
    /// No answer yet since the start, and nothing failed.
    Connecting,
    /// The last request was answered in time.
    Up,
    /// An answer is overdue: milliseconds since the first request still unanswered. Stays (and
    /// grows) through reconnections until an answer arrives.
    TimedOut(u32),
    /// The last attempt failed; stays until an answer arrives.
    Down(DownReason),
}

impl std::fmt::Display for Link {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Link::Connecting => f.write_str("connecting"),
            Link::Up => f.write_str("up"),
            Link::TimedOut(ms) => write!(f, "no answer for {ms} ms"),
            Link::Down(reason) => write!(f, "down: {reason}"),
        }
    }
}

/// What the cycle thread gets each cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModbusInput {
    /// The 8 status bytes (SCON, SPOS, ...) of the latest answer; zeros before the first.
    pub data: [u8; 8],
    /// A new answer arrived since the last `take_input`.
    pub fresh: bool,
    /// The cycle whose output image `data` answered.
    pub answered: u64,
    /// Cycles later than the one cycle of latency expected: as of this cycle
    /// (`cycle - answered - 1`), or as the answer arrived, whichever is more.
    pub late_cycles: u32,
    /// The connection's state.
    pub link: Link,
}

/// The output image as handed to the exchange thread.
#[derive(Debug, Clone, Copy)]
struct Output {
    cycle: u64,
    image: [u8; 8],
}

/// What the exchange thread publishes.
#[derive(Debug, Clone, Copy)]
struct Published {
    data: [u8; 8],
    answered: u64,
    /// Answers so far: tells the cycle side an answer is new even when a link change was
    /// published in between.
    answers: u64,
    late_cycles: u32,
    link: Link,
}

/// The cycle thread's end: no lock, no allocation, no syscall in any method.
#[derive(Debug)]
pub struct ModbusCycleSide {
    output: TripleWriter<Output>,
    input: TripleReader<Published>,
    answers_seen: u64,
}

impl ModbusCycleSide {
    /// Hands over the control image of `cycle`; the exchange thread sends the latest one.
    pub fn put_output(&mut self, cycle: u64, image: &[u8; 8]) {
        self.output.publish(Output {
            cycle,
            image: *image,
        });
    }

    /// The latest status image, as of `cycle` (see [`ModbusInput`]).
    pub fn take_input(&mut self, cycle: u64) -> ModbusInput {
        let (p, _) = self.input.read();
        let fresh = p.answers != self.answers_seen;
        self.answers_seen = p.answers;
        let age = cycle.saturating_sub(p.answered).saturating_sub(1);
        let late = if p.answers == 0 {
            0
        } else {
            u32::try_from(age).unwrap_or(u32::MAX).max(p.late_cycles)
        };
        ModbusInput {
            data: p.data,
            fresh,
            answered: p.answered,
            late_cycles: late,
            link: p.link,
        }
    }
}

/// The running exchange thread. Dropping it stops the thread too.
#[derive(Debug)]
pub struct ModbusThread {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
}

impl ModbusThread {
    /// Stops the thread (within a few milliseconds, or `connect_timeout` while connecting),
    /// closes the connection and waits for it.
    pub fn stop(mut self) {
        self.stop_and_join();
    }

    fn stop_and_join(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            // A panicked exchange thread has nothing left to clean up.
            let _ = h.join();
        }
    }
}

impl Drop for ModbusThread {
    fn drop(&mut self) {
        self.stop_and_join();
    }
}

/// Starts the exchange with the CMMO-ST at `addr`. Returns at once: the thread connects on its
/// own, and the link reads [`Link::Connecting`] until the first answer. The output image is
/// all zeros (drive disabled) until the first `put_output`. Fails only when the thread cannot
/// be started.
pub fn spawn(
    addr: SocketAddr,
    settings: ModbusSettings,
) -> io::Result<(ModbusCycleSide, ModbusThread)> {
    let (out_w, out_r) = triple_buffer(Output {
        cycle: 0,
        image: [0; 8],
    });
    let (in_w, in_r) = triple_buffer(Published {
        data: [0; 8],
        answered: 0,
        answers: 0,
        late_cycles: 0,
        link: Link::Connecting,
    });
    let stop = Arc::new(AtomicBool::new(false));
    let mut exchange = Exchange::new(addr, settings, Arc::clone(&stop), out_r, in_w);
    let handle = thread::Builder::new()
        .name(format!("modbus-{addr}"))
        .spawn(move || exchange.run())?;
    Ok((
        ModbusCycleSide {
            output: out_w,
            input: in_r,
            answers_seen: 0,
        },
        ModbusThread {
            stop,
            handle: Some(handle),
        },
    ))
}

/// The longest the thread blocks in one call, so `stop` is seen promptly.
const MAX_BLOCK: Duration = Duration::from_millis(5);

/// A request on the wire: the cycle whose output it carries, and when it was sent.
#[derive(Debug, Clone, Copy)]
struct Sent {
    cycle: u64,
    at: Instant,
}

struct Exchange {
    addr: SocketAddr,
    settings: ModbusSettings,
    stop: Arc<AtomicBool>,
    outputs: TripleReader<Output>,
    inputs: TripleWriter<Published>,
    latest: Output,
    /// An output was put since the last send.
    new_output: bool,
    conn: Option<TcpStream>,
    client: Client,
    /// Received bytes not yet framed (TCP may split or join answers).
    rx: [u8; 2 * MAX_ADU],
    rx_len: usize,
    pending: Option<Sent>,
    last_send: Instant,
    /// When the oldest request still unanswered was sent (kept across reconnections).
    silent_since: Option<Instant>,
    backoff: Duration,
    reconnect_at: Instant,
    state: Published,
}

impl Exchange {
    fn new(
        addr: SocketAddr,
        settings: ModbusSettings,
        stop: Arc<AtomicBool>,
        outputs: TripleReader<Output>,
        inputs: TripleWriter<Published>,
    ) -> Exchange {
        let now = monotonic_now();
        Exchange {
            addr,
            settings,
            stop,
            outputs,
            inputs,
            latest: Output {
                cycle: 0,
                image: [0; 8],
            },
            new_output: true,
            conn: None,
            client: Client::new(settings.unit_id),
            rx: [0; 2 * MAX_ADU],
            rx_len: 0,
            pending: None,
            last_send: now,
            silent_since: None,
            backoff: settings.backoff_min,
            reconnect_at: now,
            state: Published {
                data: [0; 8],
                answered: 0,
                answers: 0,
                late_cycles: 0,
                link: Link::Connecting,
            },
        }
    }

    fn run(&mut self) {
        while !self.stop.load(Ordering::Relaxed) {
            self.take_output();
            let now = monotonic_now();
            if let Link::TimedOut(_) = self.state.link {
                self.set_link(Link::TimedOut(self.silent_ms(now)));
            }
            if self.conn.is_none() {
                if now >= self.reconnect_at {
                    self.connect();
                } else {
                    thread::sleep(
                        self.reconnect_at
                            .saturating_duration_since(now)
                            .min(MAX_BLOCK),
                    );
                }
            } else if let Some(sent) = self.pending {
                self.await_answer(sent, now);
            } else if self.new_output
                || now.saturating_duration_since(self.last_send) >= self.settings.period
            {
                self.send(now);
            } else {
                let keepalive = self.last_send + self.settings.period;
                let wait = keepalive.saturating_duration_since(now);
                thread::sleep(wait.min(self.settings.poll).max(Duration::from_micros(20)));
            }
        }
    }

    fn take_output(&mut self) {
        let (o, fresh) = self.outputs.read();
        self.latest = o;
        self.new_output |= fresh;
    }

    fn silent_ms(&self, now: Instant) -> u32 {
        let ms = self
            .silent_since
            .map_or(0, |t| now.saturating_duration_since(t).as_millis());
        u32::try_from(ms).unwrap_or(u32::MAX)
    }

    fn set_link(&mut self, link: Link) {
        if self.state.link != link {
            self.state.link = link;
            self.inputs.publish(self.state);
        }
    }

    /// Closes the connection and schedules the next attempt after the back-off.
    fn fail(&mut self, link: Link) {
        self.conn = None;
        self.rx_len = 0;
        self.pending = None;
        self.client.cancel();
        let now = monotonic_now();
        self.reconnect_at = now + self.backoff;
        self.backoff = (self.backoff * 2).min(self.settings.backoff_max);
        self.set_link(link);
    }

    fn connect(&mut self) {
        let stream = TcpStream::connect_timeout(&self.addr, self.settings.connect_timeout)
            .and_then(|s| {
                // Requests are small and latency matters more than packing.
                s.set_nodelay(true)?;
                s.set_write_timeout(Some(self.settings.timeout))?;
                Ok(s)
            });
        match stream {
            Ok(s) => {
                self.conn = Some(s);
                self.rx_len = 0;
                self.client.cancel();
                // Send the latest image at once: the device's node guard runs from the
                // connection.
                self.new_output = true;
            }
            Err(e) => {
                let link = match self.state.link {
                    // Reconnecting after a timeout: the device is still silent, and the
                    // duration says more than the failed attempt.
                    Link::TimedOut(ms) => Link::TimedOut(ms),
                    _ => Link::Down(DownReason::Connect(e.kind())),
                };
                self.fail(link);
            }
        }
    }

    fn send(&mut self, now: Instant) {
        let mut buf = [0u8; MAX_ADU];
        let n = match self.client.exchange_image(&self.latest.image, &mut buf) {
            Ok(n) => n,
            // Only when a request is outstanding, which run() rules out; start clean.
            Err(_) => {
                self.client.cancel();
                return;
            }
        };
        let Some(conn) = self.conn.as_mut() else {
            return;
        };
        match conn.write_all(buf.get(..n).unwrap_or(&[])) {
            Ok(()) => {
                self.pending = Some(Sent {
                    cycle: self.latest.cycle,
                    at: now,
                });
                self.last_send = now;
                self.new_output = false;
                self.silent_since.get_or_insert(now);
            }
            Err(e) => self.fail(Link::Down(DownReason::Io(e.kind()))),
        }
    }

    /// Waits (a little) for the answer to `sent`; past its timeout, gives up on it, unless it
    /// is in the socket already: this thread may itself have been kept from running past the
    /// deadline (a loaded host), which is no silence of the drive.
    fn await_answer(&mut self, sent: Sent, now: Instant) {
        let due = sent.at + self.settings.timeout;
        if now < due {
            self.receive(due.saturating_duration_since(now).min(MAX_BLOCK));
            return;
        }
        self.receive(Duration::ZERO);
        if self.pending.is_some() {
            self.timed_out(now);
        }
    }

    fn timed_out(&mut self, now: Instant) {
        let ms = self.silent_ms(now);
        self.fail(Link::TimedOut(ms));
    }

    /// Waits up to `wait` for answer bytes and handles every whole frame.
    fn receive(&mut self, wait: Duration) {
        let Some(conn) = self.conn.as_mut() else {
            return;
        };
        let room = self.rx.get_mut(self.rx_len..).unwrap_or(&mut []);
        // A zero read timeout is an error in std; wait at least a little.
        let read = conn
            .set_read_timeout(Some(wait.max(Duration::from_micros(20))))
            .and_then(|()| conn.read(room));
        match read {
            Ok(0) => self.fail(Link::Down(DownReason::Closed)),
            Ok(n) => {
                self.rx_len += n;
                self.frames();
            }
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                ) => {}
            Err(e) => self.fail(Link::Down(DownReason::Io(e.kind()))),
        }
    }

    fn frames(&mut self) {
        loop {
            let buffered = self.rx.get(..self.rx_len).unwrap_or(&[]);
            let n = match client::frame_len(buffered) {
                Ok(Some(n)) => n,
                Ok(None) => return,
                Err(e) => return self.fail(Link::Down(DownReason::Response(e))),
            };
            let result = self
                .client
                .handle_response(buffered.get(..n).unwrap_or(&[]))
                .map(|r| r.image());
            self.rx.copy_within(n..self.rx_len, 0);
            self.rx_len -= n;
            match result {
                Ok(Some(image)) => self.answered(image),
                // A register answer of another length cannot come from a correct FC 0x17.
                Ok(None) => {}
                // Stale answers (to a request given up on) and answers nobody waits for are
                // dropped.
                Err(ResponseError::WrongTransaction { .. } | ResponseError::NotPending) => {}
                Err(e @ ResponseError::Exception { .. }) => {
                    // The device answered, just not with data: it is not silent.
                    self.pending = None;
                    self.silent_since = None;
                    self.set_link(Link::Down(DownReason::Response(e)));
                }
                Err(e) => return self.fail(Link::Down(DownReason::Response(e))),
            }
        }
    }

    fn answered(&mut self, image: [u8; 8]) {
        let Some(sent) = self.pending.take() else {
            return;
        };
        // The cycle thread may have moved on while the answer was on its way.
        self.take_output();
        let late = self.latest.cycle.saturating_sub(sent.cycle);
        self.state = Published {
            data: image,
            answered: sent.cycle,
            answers: self.state.answers.wrapping_add(1),
            late_cycles: u32::try_from(late).unwrap_or(u32::MAX),
            link: Link::Up,
        };
        self.inputs.publish(self.state);
        self.silent_since = None;
        self.backoff = self.settings.backoff_min;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn side() -> (
        ModbusCycleSide,
        TripleReader<Output>,
        TripleWriter<Published>,
    ) {
        let (out_w, out_r) = triple_buffer(Output {
            cycle: 0,
            image: [0; 8],
        });
        let (in_w, in_r) = triple_buffer(Published {
            data: [0; 8],
            answered: 0,
            answers: 0,
            late_cycles: 0,
            link: Link::Connecting,
        });
        (
            ModbusCycleSide {
                output: out_w,
                input: in_r,
                answers_seen: 0,
            },
            out_r,
            in_w,
        )
    }

    #[test]
    fn the_cycle_side_reports_freshness_and_age() {
        let (mut cs, mut out_r, mut in_w) = side();
        let first = cs.take_input(5);
        assert!(!first.fresh);
        assert_eq!(first.late_cycles, 0);
        assert_eq!(first.link, Link::Connecting);

        cs.put_output(7, &[1; 8]);
        let (o, fresh) = out_r.read();
        assert!(fresh);
        assert_eq!((o.cycle, o.image), (7, [1; 8]));

        let answer = Published {
            data: [2; 8],
            answered: 7,
            answers: 1,
            late_cycles: 0,
            link: Link::Up,
        };
        in_w.publish(answer);
        let on_time = cs.take_input(8);
        assert!(on_time.fresh);
        assert_eq!((on_time.answered, on_time.late_cycles), (7, 0));
        // No new answer by cycle 10: the data is two cycles late, and not fresh.
        let stale = cs.take_input(10);
        assert!(!stale.fresh);
        assert_eq!(stale.late_cycles, 2);
        // A link change is published without a new answer: still not fresh.
        in_w.publish(Published {
            link: Link::TimedOut(60),
            ..answer
        });
        let t = cs.take_input(10);
        assert!(!t.fresh);
        assert_eq!(t.link, Link::TimedOut(60));
        // The thread's own count wins when it is larger.
        in_w.publish(Published {
            answers: 2,
            answered: 9,
            late_cycles: 3,
            ..answer
        });
        let late = cs.take_input(10);
        assert!(late.fresh);
        assert_eq!(late.late_cycles, 3);
    }

    #[test]
    fn an_answer_in_the_socket_is_taken_even_when_the_thread_comes_back_late() {
        use std::io::{Read, Write};
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let (_cs, out_r, in_w) = side();
        let settings = ModbusSettings::default();
        let stop = Arc::new(AtomicBool::new(false));
        let mut ex = Exchange::new(listener.local_addr().unwrap(), settings, stop, out_r, in_w);
        ex.connect();
        let (mut server, _) = listener.accept().unwrap();
        let sent_at = monotonic_now();
        ex.send(sent_at);
        // The drive answers at once (FC 17h, 8 bytes: SCON 10h, SPOS 04h)...
        let mut req = [0u8; 25];
        server.read_exact(&mut req).unwrap();
        let mut answer = vec![req[0], req[1], 0, 0, 0, 11, req[6], 0x17, 8];
        answer.extend([0x10, 0x04, 0, 0, 0, 0, 0, 0]);
        server.write_all(&answer).unwrap();
        thread::sleep(Duration::from_millis(20));
        // ...but the exchange thread only runs again after the answer timeout.
        let sent = ex.pending.unwrap();
        ex.await_answer(sent, sent_at + settings.timeout + Duration::from_millis(30));
        assert_eq!(ex.state.link, Link::Up);
        assert_eq!((ex.state.answers, ex.state.data[0]), (1, 0x10));
        assert!(ex.pending.is_none());
        // With nothing in the socket, the same lateness is a timeout.
        let sent_at = monotonic_now();
        ex.send(sent_at);
        server.read_exact(&mut req).unwrap();
        let sent = ex.pending.unwrap();
        ex.await_answer(sent, sent_at + settings.timeout + Duration::from_millis(30));
        assert!(
            matches!(ex.state.link, Link::TimedOut(_)),
            "{:?}",
            ex.state.link
        );
    }

    #[test]
    fn a_refused_connection_is_down_and_retried() {
        // A port nobody listens on: bind, read the port, close.
        let addr = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .unwrap();
        let settings = ModbusSettings {
            backoff_min: Duration::from_millis(5),
            backoff_max: Duration::from_millis(20),
            ..ModbusSettings::default()
        };
        let (mut cs, thread) = spawn(addr, settings).unwrap();
        let mut link = Link::Connecting;
        for _ in 0..400 {
            link = cs.take_input(0).link;
            if link != Link::Connecting {
                break;
            }
            thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(
            link,
            Link::Down(DownReason::Connect(ErrorKind::ConnectionRefused))
        );
        assert_eq!(link.to_string(), "down: cannot connect: connection refused");
        thread.stop();
    }
}
