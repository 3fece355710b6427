//! PDO pack/unpack cost per frame: a typical drive mapping and the worst case this stack
//! allows (8 entries of odd bit lengths filling all 64 bits, none byte-aligned).
//!
//! Run: `cargo bench -p drivers --no-default-features --features std --bench pdo`

// criterion_group! generates an undocumented `pub fn`.
#![allow(missing_docs)]

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use drivers::canopen::Address;
use drivers::canopen::od::{AccessType, DataType, EntryDef, ObjectDictionary};
use drivers::canopen::pdo::{Mapping, MappingEntry};

/// Controlword 16 + target position 32 + 8 one-bit flags = 56 bits, 7 bytes.
fn typical() -> Mapping {
    let mut e = vec![
        MappingEntry::new(0x6040, 0, 16),
        MappingEntry::new(0x607A, 0, 32),
    ];
    e.extend((1..=6).map(|s| MappingEntry::new(0x2000, s, 1)));
    Mapping::new(&e).unwrap()
}

/// 8 entries, odd lengths, 64 bits: every entry straddles a byte boundary.
fn worst() -> Mapping {
    let lens = [1u8, 3, 7, 9, 11, 13, 17, 3];
    let e: Vec<_> = lens
        .iter()
        .enumerate()
        .map(|(i, &b)| MappingEntry::new(0x2001, i as u8 + 1, b))
        .collect();
    Mapping::new(&e).unwrap()
}

fn bench(c: &mut Criterion) {
    let values = [0x000F, 0xFFFF_FFFE, 1, 0, 1, 1, 0, 1];
    for (name, m) in [("typical", typical()), ("worst_8_odd", worst())] {
        let mut out = [0u8; 8];
        c.bench_function(&format!("pack_{name}"), |b| {
            b.iter(|| black_box(&m).pack(black_box(&values), &mut out))
        });
        m.pack(&values, &mut out);
        let mut back = [0u64; 8];
        c.bench_function(&format!("unpack_{name}"), |b| {
            b.iter(|| black_box(&m).unpack(black_box(&out), &mut back))
        });
    }

    // The device path: pack straight from a 64-entry dictionary.
    let mut od: ObjectDictionary<'static, 64, 512> = ObjectDictionary::new();
    od.insert(
        EntryDef::new(
            Address::new(0x6040, 0),
            "cw",
            DataType::Unsigned16,
            AccessType::Rww,
        )
        .mappable(),
    )
    .unwrap();
    od.insert(
        EntryDef::new(
            Address::new(0x607A, 0),
            "t",
            DataType::Integer32,
            AccessType::Rww,
        )
        .mappable(),
    )
    .unwrap();
    for s in 1..=62u8 {
        od.insert(
            EntryDef::new(
                Address::new(0x2000, s),
                "f",
                DataType::Boolean,
                AccessType::Rw,
            )
            .mappable(),
        )
        .unwrap();
    }
    let m = typical();
    let mut out = [0u8; 8];
    c.bench_function("pack_typical_from_od64", |b| {
        b.iter(|| m.pack_from_od(black_box(&od), &mut out))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
