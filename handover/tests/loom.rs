//! The triple buffer under loom: every interleaving of a writer and a reader (bounded by loom's
//! preemption bound), with every slot access checked for a data race.
//!
//! `RUSTFLAGS="--cfg loom" cargo test -p handover --release --test loom` (`.ci/run` runs it).
#![cfg(loom)]

use handover::triple_buffer::triple_buffer;

/// Two-word values: a torn read would show two different halves.
fn value(k: u32) -> [u32; 2] {
    [k, k]
}

#[test]
fn the_reader_sees_whole_values_in_order_and_the_last_one_at_the_end() {
    loom::model(|| {
        let (mut w, mut r) = triple_buffer(value(0));
        let writer = loom::thread::spawn(move || {
            for k in 1..=3 {
                w.publish(value(k));
            }
        });
        let mut last = 0;
        for _ in 0..3 {
            let (v, fresh) = r.read();
            assert_eq!(v[0], v[1], "torn read");
            assert!(v[0] >= last, "went back from {last} to {}", v[0]);
            if !fresh {
                assert_eq!(v[0], last, "a changed value must be reported fresh");
            }
            last = v[0];
        }
        writer.join().unwrap();
        // Once the writer is done, the last value is there (fresh unless already read).
        let (v, fresh) = r.read();
        assert_eq!(v, value(3));
        assert_eq!(fresh, last != 3);
    });
}

#[test]
fn a_value_read_is_never_the_slot_being_written() {
    // Many publications against one read each side: loom reports any concurrent access to one
    // slot (the writer writing the slot the reader reads) as a causality violation.
    loom::model(|| {
        let (mut w, mut r) = triple_buffer(value(0));
        let writer = loom::thread::spawn(move || {
            w.publish(value(1));
            w.publish(value(2));
        });
        let reader = loom::thread::spawn(move || {
            let a = r.read().0;
            let b = r.read().0;
            assert!(a[0] == a[1] && b[0] == b[1] && b[0] >= a[0]);
        });
        writer.join().unwrap();
        reader.join().unwrap();
    });
}
