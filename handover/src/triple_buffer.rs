//! A wait-free single-writer, single-reader "latest value" channel between the cycle thread
//! and an I/O thread. `unsafe` appears only in the slot access, with its `SAFETY` argument.

use core::fmt;

use crate::sync::{Arc, AtomicU8, Ordering, UnsafeCell};

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
// threads only ever moves `T` values between them, which `T: Send` allows. Checked by loom
// (tests/loom.rs) and miri.
unsafe impl<T: Send> Sync for Slots<T> {}

impl<T> Slots<T> {
    fn slot(&self, i: u8) -> &UnsafeCell<T> {
        // The modulo keeps a corrupted index from panicking; it cannot occur (see above).
        &self.slots[usize::from(i % 3)]
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
/// cycle side must be provably free of locks and allocation (docs/decisions.md).
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
        self.shared
            .slot(self.index)
            .with_mut(|p| unsafe { p.write(value) });
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
        let value = self.shared.slot(self.index).with(|p| unsafe { p.read() });
        (value, fresh)
    }
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::*;

    #[test]
    fn triple_buffer_hands_over_whole_values_under_contention() {
        // Each value is 16 copies of one counter: a torn read would mix two counters. Miri runs
        // the same test, a thousand times slower: fewer values there.
        const N: u64 = if cfg!(miri) { 300 } else { 200_000 };
        let (mut w, mut r) = triple_buffer([0u64; 16]);
        let writer = std::thread::spawn(move || {
            for k in 1..=N {
                w.publish([k; 16]);
            }
        });
        let mut last = 0;
        let mut fresh_reads = 0u64;
        loop {
            // Sampled before the read: once the writer has finished, a read must see N. The
            // fence makes the writer's last hand-over visible here (is_finished reads the end of
            // the thread without ordering; miri's weak-memory emulation shows the difference).
            let finished = writer.is_finished();
            if finished {
                std::sync::atomic::fence(std::sync::atomic::Ordering::Acquire);
            }
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

    #[test]
    fn a_read_without_a_publication_gives_the_initial_value_not_fresh() {
        let (mut w, mut r) = triple_buffer(5u8);
        assert_eq!(r.read(), (5, false));
        w.publish(6);
        w.publish(7);
        // The values in between are overwritten: the latest only.
        assert_eq!(r.read(), (7, true));
        assert_eq!(r.read(), (7, false));
        w.publish(8);
        assert_eq!(r.read(), (8, true));
    }
}
