//! Puts received frames back into timestamp order for captures.
//!
//! On the cross-process bus (`vbus:NAME`, [`super::shm_bus`]) every sender models its own bit
//! timing, a frame's timestamp is its modelled completion time, which may lie up to the
//! sender's backlog in the future, and frames are delivered on arrival. Frames of different
//! senders therefore arrive out of timestamp order. A [`ReorderBuffer`] holds frames as they
//! arrive and releases them in timestamp order (frames with equal timestamps in arrival order)
//! once they are older than the horizon `now - window`, so that a later arrival can no longer
//! precede them.
//!
//! The guarantee: if every frame is pushed no later than `window` after its timestamp (its
//! *lateness*, `now - timestamp` at the push, is at most the window; frames stamped in the
//! future have none), the frames come out sorted. Memory is bounded: when the buffer holds
//! `capacity` frames, a push releases the oldest one early and counts it.
//!
//! ```
//! use drivers::can::{reorder::ReorderBuffer, Frame};
//! use drivers::time::Instant;
//! use core::time::Duration;
//! let mut buf = ReorderBuffer::new(Duration::from_millis(10), 1024);
//! let late = Frame::std8(0x181, [0; 8]).with_timestamp(Instant::from_millis(3));
//! let early = Frame::std8(0x182, [0; 8]).with_timestamp(Instant::from_millis(2));
//! assert_eq!(buf.push(late), None);
//! assert_eq!(buf.push(early), None);
//! assert_eq!(buf.pop_ready(Instant::from_millis(5)), None); // still within the window
//! let out: Vec<_> = std::iter::from_fn(|| buf.pop_ready(Instant::from_millis(20))).collect();
//! assert_eq!(out, [early, late]);
//! ```

use super::Frame;
#[cfg(feature = "shm")]
use super::shm_bus::TX_BACKLOG_FRAMES;
use crate::time::Instant;
use core::cmp::{Ordering, Reverse};
use core::time::Duration;
use std::collections::BinaryHeap;

/// Slack for delivery on top of the modelled backlog: receivers poll (every 100 µs in
/// `ShmBus::recv_until`, every millisecond or so in capture threads), work through what they
/// received, and a sender may be preempted between stamping a frame and publishing it. Generous,
/// because a loaded machine stretches all of these; a human reading `canbus dump` does not
/// notice 50 ms.
pub const DELIVERY_MARGIN: Duration = Duration::from_millis(50);

/// Frames a buffer from [`ReorderBuffer::for_shm_bus`] holds before it releases early: about
/// half a second of a fully loaded 1 Mbit/s bus, several times the window's worth at any
/// bitrate.
pub const DEFAULT_CAPACITY: usize = 4096;

/// The reorder window for a `vbus:` bus at `bitrate` bit/s: how far ahead of the clock a
/// sender may stamp a frame, by which that frame may arrive before an earlier-stamped one of
/// another sender (the [`TX_BACKLOG_FRAMES`] worst-case frames it may queue behind, plus the
/// frame itself: extended, 8 data bytes, at that bitrate), plus [`DELIVERY_MARGIN`].
/// 10.4 ms + 50 ms at 1 Mbit/s, 520 ms + 50 ms at 20 kbit/s.
#[cfg(feature = "shm")]
pub fn shm_window(bitrate: u32) -> Duration {
    use super::bit_timing::{bits_duration, worst_case_bits};
    let frame = bits_duration(worst_case_bits(true, 8), bitrate);
    frame * (TX_BACKLOG_FRAMES + 1) + DELIVERY_MARGIN
}

/// A held frame, ordered by timestamp and then by arrival.
#[derive(Debug, Clone, Copy)]
struct Held {
    timestamp: Instant,
    seq: u64,
    frame: Frame,
}

impl PartialEq for Held {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Held {}
impl PartialOrd for Held {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Held {
    fn cmp(&self, other: &Self) -> Ordering {
        (self.timestamp, self.seq).cmp(&(other.timestamp, other.seq))
    }
}

/// A bounded buffer that releases frames in timestamp order; see the module docs.
#[derive(Debug)]
pub struct ReorderBuffer {
    // Min-heap on (timestamp, arrival): the next frame to release is at the top.
    heap: BinaryHeap<Reverse<Held>>,
    window: Duration,
    capacity: usize,
    seq: u64,
    released_early: u64,
    late: u64,
    last_released: Option<Instant>,
}

impl ReorderBuffer {
    /// A buffer that holds each frame until `window` after its timestamp, and at most
    /// `capacity` frames (at least 1). Allocates its storage now, none later.
    pub fn new(window: Duration, capacity: usize) -> Self {
        let capacity = capacity.max(1);
        ReorderBuffer {
            // One spare slot: a push into a full buffer inserts before it releases the oldest.
            heap: BinaryHeap::with_capacity(capacity + 1),
            window,
            capacity,
            seq: 0,
            released_early: 0,
            late: 0,
            last_released: None,
        }
    }

    /// A buffer for a `vbus:` bus at `bitrate` bit/s: window [`shm_window`], capacity
    /// [`DEFAULT_CAPACITY`].
    #[cfg(feature = "shm")]
    pub fn for_shm_bus(bitrate: u32) -> Self {
        ReorderBuffer::new(shm_window(bitrate), DEFAULT_CAPACITY)
    }

    /// How long after its timestamp a frame is held.
    pub fn window(&self) -> Duration {
        self.window
    }

    /// The most frames held at once.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Frames held now.
    pub fn len(&self) -> usize {
        self.heap.len()
    }

    /// Whether no frame is held.
    pub fn is_empty(&self) -> bool {
        self.heap.is_empty()
    }

    /// Frames released before their window passed because the buffer was full.
    pub fn released_early(&self) -> u64 {
        self.released_early
    }

    /// Frames that arrived with a timestamp before one already released: they come out of
    /// order (their lateness exceeded the window, or an early release overtook them).
    pub fn late(&self) -> u64 {
        self.late
    }

    /// Takes a frame as it arrives. When the buffer was full, returns the oldest frame (which
    /// may be this one) for release now, and counts it as released early.
    pub fn push(&mut self, frame: Frame) -> Option<Frame> {
        let timestamp = frame.timestamp();
        if self.last_released.is_some_and(|t| timestamp < t) {
            self.late += 1;
        }
        self.heap.push(Reverse(Held {
            timestamp,
            seq: self.seq,
            frame,
        }));
        self.seq += 1;
        if self.heap.len() > self.capacity {
            self.released_early += 1;
            return self.pop_oldest();
        }
        None
    }

    /// The oldest held frame if it is older than the horizon `now - window`.
    pub fn pop_ready(&mut self, now: Instant) -> Option<Frame> {
        let Reverse(top) = self.heap.peek()?;
        if top.timestamp.saturating_add(self.window) < now {
            self.pop_oldest()
        } else {
            None
        }
    }

    /// The oldest held frame, whatever the time: flushing at the end of a capture is calling
    /// this until it returns `None`.
    pub fn pop_oldest(&mut self) -> Option<Frame> {
        let Reverse(held) = self.heap.pop()?;
        self.last_released = Some(
            self.last_released
                .map_or(held.timestamp, |t| t.max(held.timestamp)),
        );
        Some(held.frame)
    }

    /// When [`pop_ready`](Self::pop_ready) will next release a frame (the oldest's timestamp
    /// plus the window, plus 1 ns); `None` when empty. For sleeping until then.
    pub fn next_release(&self) -> Option<Instant> {
        self.heap.peek().map(|Reverse(h)| {
            h.timestamp
                .saturating_add(self.window)
                .saturating_add(Duration::from_nanos(1))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn frame(id: u16, t_us: u64) -> Frame {
        Frame::new_std(id, &id.to_le_bytes())
            .unwrap()
            .with_timestamp(Instant::from_micros(t_us))
    }

    fn ids(frames: &[Frame]) -> Vec<u32> {
        frames.iter().map(|f| f.raw_id()).collect()
    }

    fn ready(buf: &mut ReorderBuffer, now_us: u64) -> Vec<Frame> {
        std::iter::from_fn(|| buf.pop_ready(Instant::from_micros(now_us))).collect()
    }

    fn flush(buf: &mut ReorderBuffer) -> Vec<Frame> {
        std::iter::from_fn(|| buf.pop_oldest()).collect()
    }

    #[test]
    fn holds_until_the_horizon_passes_then_releases_in_order() {
        let mut buf = ReorderBuffer::new(Duration::from_micros(100), 16);
        // Sender A's frame stamped in the future arrives before B's earlier one.
        assert_eq!(buf.push(frame(0x1, 1_500)), None);
        assert_eq!(buf.push(frame(0x2, 1_050)), None);
        assert_eq!(buf.push(frame(0x3, 1_200)), None);
        assert!(ready(&mut buf, 1_100).is_empty());
        // The horizon is strict: exactly window after the timestamp is not yet older.
        assert!(ready(&mut buf, 1_150).is_empty());
        assert_eq!(buf.next_release(), Some(Instant::from_nanos(1_150_001)));
        assert_eq!(ids(&ready(&mut buf, 1_301)), [0x2, 0x3]);
        assert_eq!(buf.len(), 1);
        assert_eq!(ids(&flush(&mut buf)), [0x1]);
        assert!(buf.is_empty());
        assert_eq!(buf.next_release(), None);
        assert_eq!((buf.released_early(), buf.late()), (0, 0));
    }

    #[test]
    fn equal_timestamps_keep_arrival_order() {
        let mut buf = ReorderBuffer::new(Duration::ZERO, 16);
        for id in [0x7, 0x3, 0x5, 0x1] {
            buf.push(frame(id, 10));
        }
        buf.push(frame(0x9, 5));
        assert_eq!(ids(&flush(&mut buf)), [0x9, 0x7, 0x3, 0x5, 0x1]);
    }

    #[test]
    fn a_full_buffer_releases_the_oldest_early_and_counts_it() {
        let mut buf = ReorderBuffer::new(Duration::from_secs(1), 2);
        assert_eq!(buf.push(frame(0x1, 30)), None);
        assert_eq!(buf.push(frame(0x2, 20)), None);
        assert_eq!(buf.push(frame(0x3, 10)).map(|f| f.raw_id()), Some(0x3));
        assert_eq!(buf.push(frame(0x4, 40)).map(|f| f.raw_id()), Some(0x2));
        assert_eq!(buf.released_early(), 2);
        assert_eq!(buf.len(), 2);
        // A frame older than one already released comes out of order and is counted.
        assert_eq!(buf.push(frame(0x5, 15)).map(|f| f.raw_id()), Some(0x5));
        assert_eq!(buf.late(), 1);
        assert_eq!(ids(&flush(&mut buf)), [0x1, 0x4]);
    }

    #[cfg(feature = "shm")]
    #[test]
    fn shm_window_covers_the_backlog_at_the_bitrate() {
        // 64 queued and 1 own extended 8-byte frames (160 bits) at 1 Mbit/s and 20 kbit/s,
        // plus the margin.
        assert_eq!(
            shm_window(1_000_000),
            Duration::from_micros(65 * 160) + DELIVERY_MARGIN
        );
        assert_eq!(
            shm_window(20_000),
            Duration::from_micros(65 * 8_000) + DELIVERY_MARGIN
        );
        let buf = ReorderBuffer::for_shm_bus(125_000);
        assert_eq!(buf.window(), shm_window(125_000));
        assert_eq!(buf.capacity(), DEFAULT_CAPACITY);
        assert_eq!(ReorderBuffer::new(Duration::ZERO, 0).capacity(), 1);
    }

    /// One arrival: time since the previous one, and the frame's timestamp relative to the
    /// clock at arrival (negative: late by that much; positive: stamped in the future).
    fn arrivals(window_us: i64) -> impl Strategy<Value = Vec<(u64, i64)>> {
        proptest::collection::vec((0u64..200, -window_us..=5 * window_us), 0..300)
    }

    proptest! {
        #[test]
        fn output_is_sorted_when_lateness_is_within_the_window(
            window_us in 0i64..2_000,
            input in arrivals(2_000),
            poll_every in 1usize..8,
        ) {
            let window = Duration::from_micros(window_us as u64);
            let mut buf = ReorderBuffer::new(window, 1024);
            let mut now = 1_000_000u64;
            let mut out = Vec::new();
            for (k, &(gap, offset)) in input.iter().enumerate() {
                now += gap;
                // Clamp lateness to the window: the precondition of the guarantee.
                let t = (now as i64 + offset.max(-window_us)) as u64;
                let f = Frame::new_std(0x100, &(k as u32).to_be_bytes()).unwrap()
                    .with_timestamp(Instant::from_micros(t));
                if let Some(f) = buf.push(f) {
                    out.push(f);
                }
                // Release at irregular moments, as a receiver between polls would.
                if k % poll_every == 0 {
                    out.extend(ready(&mut buf, now));
                }
            }
            out.extend(flush(&mut buf));
            prop_assert_eq!(out.len(), input.len());
            prop_assert_eq!(buf.released_early(), 0);
            prop_assert_eq!(buf.late(), 0);
            for w in out.windows(2) {
                let (a, b) = (w[0].timestamp(), w[1].timestamp());
                prop_assert!(a <= b, "{} then {}", a, b);
                if a == b {
                    // Stable: arrival order (the big-endian index in the payload) among equal
                    // timestamps.
                    prop_assert!(w[0].data() < w[1].data());
                }
            }
            // Every frame exactly once.
            let mut seen: Vec<&[u8]> = out.iter().map(|f| f.data()).collect();
            seen.sort();
            seen.dedup();
            prop_assert_eq!(seen.len(), input.len());
        }
    }
}
