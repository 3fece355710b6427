//! The virtual CAN bus across processes, over iceoryx2 shared memory: `vbus:NAME`.
//!
//! Every bus is one iceoryx2 publish-subscribe service named `vbus/NAME` with payload
//! [`ShmCanSample`]. Every endpoint ([`ShmBus`]) owns one publisher and one subscriber on it;
//! the service allows [`MAX_ENDPOINTS`] of each and uses *safe overflow*, so a full receive
//! buffer drops its oldest sample instead of blocking the sender: a dead or slow process never
//! stalls the others.
//!
//! # Timing
//!
//! This bus runs in real time on `CLOCK_MONOTONIC`, which is system-wide, so timestamps from
//! different processes compare directly. Each sender models its own bit timing: a frame
//! completes at `max(now, end of this sender's previous frame) + worst-case frame duration` at
//! the bus bitrate ([`crate::can::bit_timing::frame_duration`]), and that completion time is
//! the frame's timestamp. A sender whose modelled backlog exceeds [`TX_BACKLOG_FRAMES`]
//! worst-case frames gets [`BusError::WouldBlock`], like a full transmit queue. Frames are
//! delivered on arrival (the timestamp may lie up to the backlog in the future); receivers skip
//! their own frames and deliver the others in arrival order.
//!
//! Senders in different processes do not arbitrate against each other: their frames may
//! overlap in modelled time. Exact arbitration, fault injection and virtual time are the job of
//! the in-process virtual bus; this bus connects processes (simulated drives, `canbus dump`,
//! tools in other languages).
//!
//! # Lifetimes
//!
//! A sample lives in its sender's shared memory. A receiver connects to a sender when it polls
//! ([`Bus::try_recv`]) while that sender is alive; frames of a sender that has already gone
//! before the receiver's first poll are lost. Long-lived endpoints (drives, the coordinator,
//! `canbus dump`) poll all the time; short-lived senders stay open briefly after their last
//! frame (`canbus send` lingers 250 ms). Endpoints that die (even by SIGKILL) leave resources
//! that the next [`ShmBus::open`] on the machine removes (iceoryx2 dead-node cleanup).
//!
//! # Sample layout (for tools in other languages)
//!
//! Service `vbus/NAME`, messaging pattern publish-subscribe, payload type name
//! `motion::vbus::CanSample`, no user header, 32 bytes, `#[repr(C)]`, host byte order
//! (little-endian on x86-64 and ARM):
//!
//! | offset | type | field | meaning |
//! |---|---|---|---|
//! | 0 | u64 | `sender` | unique id of the sending endpoint (receivers skip their own) |
//! | 8 | u64 | `timestamp_ns` | completion time, `CLOCK_MONOTONIC` nanoseconds |
//! | 16 | u32 | `can_id` | SocketCAN `can_id`: identifier, EFF `0x8000_0000`, RTR `0x4000_0000` |
//! | 20 | u8 | `len` | data length (the DLC for remote frames) |
//! | 21 | [u8; 3] | `reserved` | zero |
//! | 24 | [u8; 8] | `data` | data bytes, zero past `len` |
//!
//! Service QoS (an opener must ask for the same): max publishers and subscribers
//! [`MAX_ENDPOINTS`], max nodes [`MAX_NODES`], history 0, subscriber buffer
//! [`SUBSCRIBER_BUFFER`], safe overflow on.

use super::bit_timing::{self, frame_duration};
use super::pcap::{frame_from_socketcan, socketcan_id};
use super::{Bus, BusCounters, BusError, BusState, Frame};
use crate::time::{Instant, monotonic_now};
use core::time::Duration;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeCreateError, PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use std::sync::Once;
use std::sync::atomic::{AtomicU32, Ordering};

/// Publishers and subscribers a bus service allows (one of each per endpoint).
pub const MAX_ENDPOINTS: usize = 32;
/// iceoryx2 nodes a bus service allows.
pub const MAX_NODES: usize = 64;
/// Samples a subscriber buffers before the oldest is overwritten.
pub const SUBSCRIBER_BUFFER: usize = 512;
/// How many worst-case frames of modelled backlog a sender may queue before `WouldBlock`.
pub const TX_BACKLOG_FRAMES: u32 = 64;
/// How long [`ShmBus::recv_until`](Bus::recv_until) sleeps between polls.
pub const POLL_INTERVAL: Duration = Duration::from_micros(100);

/// One CAN frame on the shared-memory bus; see the module docs for the layout.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("motion::vbus::CanSample")]
pub struct ShmCanSample {
    /// Unique id of the sending endpoint.
    pub sender: u64,
    /// Completion time on `CLOCK_MONOTONIC`, nanoseconds.
    pub timestamp_ns: u64,
    /// SocketCAN `can_id` (identifier with EFF and RTR flags).
    pub can_id: u32,
    /// Data length, or the DLC of a remote frame.
    pub len: u8,
    /// Zero.
    pub reserved: [u8; 3],
    /// Data bytes, zero past `len`.
    pub data: [u8; 8],
}

impl ShmCanSample {
    /// The sample for `frame` sent by `sender`, completing at `timestamp`.
    pub fn from_frame(sender: u64, timestamp: Instant, frame: &Frame) -> ShmCanSample {
        let mut data = [0u8; 8];
        let d = frame.data();
        data[..d.len()].copy_from_slice(d);
        ShmCanSample {
            sender,
            timestamp_ns: timestamp.as_nanos(),
            can_id: socketcan_id(frame),
            len: frame.dlc(),
            reserved: [0; 3],
            data,
        }
    }

    /// The frame, with the sample's timestamp. A peer's malformed sample yields an error.
    pub fn to_frame(&self) -> Result<Frame, super::pcap::PcapError> {
        Ok(frame_from_socketcan(self.can_id, self.len, &self.data)?
            .with_timestamp(Instant::from_nanos(self.timestamp_ns)))
    }
}

/// Why a shared-memory bus could not be opened.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ShmBusError {
    /// The bus name is not a valid iceoryx2 service name.
    #[error("invalid virtual bus name `{name}`: {reason}")]
    Name {
        /// The name given.
        name: String,
        /// Why iceoryx2 refused it.
        reason: String,
    },
    /// The bitrate is outside 20 kbit/s..1 Mbit/s.
    #[error("bitrate {0} bit/s is outside {min}..={max}", min = bit_timing::MIN_BITRATE, max = bit_timing::MAX_BITRATE)]
    Bitrate(u32),
    /// iceoryx2 refused to create the node, service or ports.
    #[error("virtual bus `vbus:{name}`: {step} failed: {reason}")]
    Iceoryx {
        /// The bus name.
        name: String,
        /// What was being created.
        step: &'static str,
        /// iceoryx2's error.
        reason: String,
    },
}

/// The iceoryx2 service name of bus `name`.
pub fn service_name(name: &str) -> String {
    format!("vbus/{name}")
}

fn unique_sender_id() -> u64 {
    static COUNTER: AtomicU32 = AtomicU32::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    // pid in the high half keeps ids unique across live processes; the low bits of the clock
    // make a recycled pid unlikely to collide with stale samples of its predecessor.
    let salt = (monotonic_now().as_nanos() as u32) & 0xFFFF_0000;
    (u64::from(std::process::id()) << 32) | u64::from(salt ^ n)
}

/// One endpoint on a cross-process virtual bus.
///
/// Not `Send`: it uses iceoryx2's single-threaded `ipc` service, whose ports take no locks.
/// Open it on the thread that uses it (the real-time thread opens its own endpoint).
pub struct ShmBus {
    name: String,
    bitrate: u32,
    sender: u64,
    tx_end: Instant,
    counters: BusCounters,
    // Ports before the node: they are dropped first.
    publisher: Publisher<ipc::Service, ShmCanSample, ()>,
    subscriber: Subscriber<ipc::Service, ShmCanSample, ()>,
    _node: Node<ipc::Service>,
}

impl core::fmt::Debug for ShmBus {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ShmBus")
            .field("name", &self.name)
            .field("bitrate", &self.bitrate)
            .field("sender", &format_args!("{:#018x}", self.sender))
            .field("counters", &self.counters)
            .finish()
    }
}

/// How often [`ShmBus::open`] asks again while another process is creating the bus (10 ms
/// apart: two seconds).
const OPEN_ATTEMPTS: u32 = 200;

/// Whether `open_or_create` failed only because another process is creating or removing the
/// same service at this moment.
fn transient(e: &PublishSubscribeOpenOrCreateError) -> bool {
    use PublishSubscribeCreateError as C;
    use PublishSubscribeOpenError as O;
    matches!(
        e,
        PublishSubscribeOpenOrCreateError::SystemInFlux
            | PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
                O::DoesNotExist | O::HangsInCreation | O::IsMarkedForDestruction
            )
            | PublishSubscribeOpenOrCreateError::PublishSubscribeCreateError(
                C::AlreadyExists | C::IsBeingCreatedByAnotherInstance | C::HangsInCreation
            )
    )
}

/// Why the bus's service could not be opened, in words where the cause is a user's to act on.
fn open_error_in_words(e: &PublishSubscribeOpenOrCreateError) -> String {
    use PublishSubscribeCreateError as C;
    use PublishSubscribeOpenError as O;
    use PublishSubscribeOpenOrCreateError as E;
    match e {
        E::PublishSubscribeOpenError(O::InsufficientPermissions)
        | E::PublishSubscribeCreateError(C::InsufficientPermissions) => {
            "no permission for its files in /dev/shm (another user's bus?)".into()
        }
        E::PublishSubscribeOpenError(O::ServiceInCorruptedState)
        | E::PublishSubscribeCreateError(C::ServiceInCorruptedState) => {
            "its files in /dev/shm are damaged (a process crashed while creating it): remove the bus's iox2 files there".into()
        }
        E::PublishSubscribeOpenError(
            O::IncompatibleTypes
            | O::IncompatibleAttributes
            | O::IncompatibleMessagingPattern
            | O::IncompatibleOverflowBehavior,
        ) => "it exists with other settings (made by another version of this software?)".into(),
        E::PublishSubscribeOpenError(
            O::DoesNotSupportRequestedAmountOfPublishers
            | O::DoesNotSupportRequestedAmountOfSubscribers
            | O::DoesNotSupportRequestedAmountOfNodes
            | O::ExceedsMaxNumberOfNodes,
        ) => format!("it is full: at most {MAX_NODES} processes join one bus"),
        E::PublishSubscribeOpenError(O::DoesNotExist | O::HangsInCreation)
        | E::SystemInFlux
        | E::PublishSubscribeCreateError(C::IsBeingCreatedByAnotherInstance | C::HangsInCreation) => {
            "another process kept creating or removing it for two seconds".into()
        }
        other => format!("iceoryx2 reports {other:?}"),
    }
}

impl ShmBus {
    /// Joins (or creates) bus `name` at `bitrate` bit/s. Removes what crashed processes left
    /// behind first. iceoryx2 logs at `Error` level unless `IOX2_LOG_LEVEL` says otherwise, and
    /// installs no signal handlers.
    pub fn open(name: &str, bitrate: u32) -> Result<ShmBus, ShmBusError> {
        if !(bit_timing::MIN_BITRATE..=bit_timing::MAX_BITRATE).contains(&bitrate) {
            return Err(ShmBusError::Bitrate(bitrate));
        }
        static LOG: Once = Once::new();
        // The missing-config warning would otherwise go to every tool's stderr.
        LOG.call_once(|| set_log_level_from_env_or(LogLevel::Error));
        let fail = |step: &'static str, e: &dyn core::fmt::Debug| ShmBusError::Iceoryx {
            name: name.to_owned(),
            step,
            reason: format!("{e:?}"),
        };
        let service: ServiceName =
            service_name(name)
                .as_str()
                .try_into()
                .map_err(|e| ShmBusError::Name {
                    name: name.to_owned(),
                    reason: format!("{e:?}"),
                })?;
        let node = NodeBuilder::new()
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| fail("creating the iceoryx2 node", &e))?;
        // Dead processes keep publisher/subscriber slots and shared memory until someone
        // cleans up; do it before taking slots ourselves.
        let _ = node.try_cleanup_dead_nodes();
        // Two processes joining a new bus at once race in open_or_create: the one that loses
        // can find the service half made (it "does not exist" yet, or "hangs in creation").
        // Those states pass within milliseconds; ask again, for a bounded time.
        let mut attempt = 0;
        let factory = loop {
            let r = node
                .service_builder(&service)
                .publish_subscribe::<ShmCanSample>()
                .max_publishers(MAX_ENDPOINTS)
                .max_subscribers(MAX_ENDPOINTS)
                .max_nodes(MAX_NODES)
                .history_size(0)
                .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
                .enable_safe_overflow(true)
                .open_or_create();
            match r {
                Ok(f) => break f,
                Err(e) if attempt < OPEN_ATTEMPTS && transient(&e) => {
                    attempt += 1;
                    std::thread::sleep(Duration::from_millis(10));
                }
                Err(e) => {
                    return Err(ShmBusError::Iceoryx {
                        name: name.to_owned(),
                        step: "opening the service",
                        reason: open_error_in_words(&e),
                    });
                }
            }
        };
        let subscriber = factory
            .subscriber_builder()
            .buffer_size(SUBSCRIBER_BUFFER)
            .create()
            .map_err(|e| fail("creating the subscriber", &e))?;
        let publisher = factory
            .publisher_builder()
            .create()
            .map_err(|e| fail("creating the publisher", &e))?;
        Ok(ShmBus {
            name: name.to_owned(),
            bitrate,
            sender: unique_sender_id(),
            tx_end: Instant::ZERO,
            counters: BusCounters::default(),
            publisher,
            subscriber,
            _node: node,
        })
    }

    /// The bus name (without `vbus:`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The bitrate the sender models.
    pub fn bitrate(&self) -> u32 {
        self.bitrate
    }

    /// This endpoint's sender id (as written into its samples).
    pub fn sender_id(&self) -> u64 {
        self.sender
    }

    /// When this endpoint's last frame completes on the modelled bus.
    pub fn tx_end(&self) -> Instant {
        self.tx_end
    }
}

/// The completion time of a frame taking `duration` on the wire, queued at `now` behind a
/// previous frame ending at `prev_end`. `None` when the backlog would exceed `max_backlog`.
pub fn completion_time(
    now: Instant,
    prev_end: Instant,
    duration: Duration,
    max_backlog: Duration,
) -> Option<Instant> {
    let start = now.max(prev_end);
    if start - now > max_backlog {
        return None;
    }
    Some(start + duration)
}

impl Bus for ShmBus {
    fn send(&mut self, frame: &Frame) -> Result<(), BusError> {
        let now = monotonic_now();
        let max_backlog = bit_timing::bits_duration(
            bit_timing::worst_case_bits(true, 8) * TX_BACKLOG_FRAMES,
            self.bitrate,
        );
        let end = completion_time(
            now,
            self.tx_end,
            frame_duration(frame, self.bitrate),
            max_backlog,
        )
        .ok_or(BusError::WouldBlock)?;
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|_| BusError::WouldBlock)?;
        let sample = sample.write_payload(ShmCanSample::from_frame(self.sender, end, frame));
        sample.send().map_err(|_| BusError::Disconnected)?;
        self.tx_end = end;
        self.counters.sent += 1;
        Ok(())
    }

    fn try_recv(&mut self) -> Result<Option<Frame>, BusError> {
        loop {
            let sample = match self.subscriber.receive() {
                Ok(Some(s)) => s,
                Ok(None) => return Ok(None),
                // A publisher that vanished mid-connection: skip, the bus goes on.
                Err(_) => {
                    self.counters.dropped += 1;
                    return Ok(None);
                }
            };
            let s = *sample.payload();
            drop(sample);
            if s.sender == self.sender {
                continue;
            }
            match s.to_frame() {
                Ok(f) => {
                    self.counters.received += 1;
                    return Ok(Some(f));
                }
                Err(_) => self.counters.dropped += 1,
            }
        }
    }

    fn recv_until(&mut self, deadline: Instant) -> Result<Option<Frame>, BusError> {
        loop {
            if let Some(f) = self.try_recv()? {
                return Ok(Some(f));
            }
            let now = monotonic_now();
            if now >= deadline {
                return Ok(None);
            }
            // No event service on this bus (keeps senders cheap): poll at a fine interval.
            std::thread::sleep(POLL_INTERVAL.min(deadline - now));
        }
    }

    fn now(&self) -> Instant {
        monotonic_now()
    }

    fn state(&self) -> BusState {
        BusState::ErrorActive
    }

    fn counters(&self) -> BusCounters {
        self.counters
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_layout_is_the_documented_one() {
        assert_eq!(core::mem::size_of::<ShmCanSample>(), 32);
        assert_eq!(core::mem::offset_of!(ShmCanSample, timestamp_ns), 8);
        assert_eq!(core::mem::offset_of!(ShmCanSample, can_id), 16);
        assert_eq!(core::mem::offset_of!(ShmCanSample, len), 20);
        assert_eq!(core::mem::offset_of!(ShmCanSample, data), 24);
        let f = Frame::new_ext(0x1234_5678, &[1, 2]).unwrap();
        let s = ShmCanSample::from_frame(7, Instant::from_nanos(99), &f);
        assert_eq!(s.can_id, 0x9234_5678);
        assert_eq!(s.len, 2);
        let back = s.to_frame().unwrap();
        assert_eq!(back, f);
        assert_eq!(back.timestamp(), Instant::from_nanos(99));
        let bad = ShmCanSample { len: 12, ..s };
        assert!(bad.to_frame().is_err());
    }

    #[test]
    fn sender_models_its_bit_timing() {
        let d = Duration::from_micros(135);
        let cap = Duration::from_millis(1);
        let t0 = Instant::from_millis(10);
        // Idle bus: completes one frame time after now.
        assert_eq!(completion_time(t0, Instant::ZERO, d, cap), Some(t0 + d));
        // Back to back: queues behind the previous frame.
        let e1 = t0 + d;
        assert_eq!(completion_time(t0, e1, d, cap), Some(e1 + d));
        // Backlog beyond the cap: the transmit queue is full.
        assert_eq!(
            completion_time(t0, t0 + Duration::from_millis(2), d, cap),
            None
        );
    }

    #[test]
    fn rejects_a_bitrate_outside_classic_can() {
        assert_eq!(ShmBus::open("x", 1).unwrap_err(), ShmBusError::Bitrate(1));
    }
}
