//! Bus admission: the worst-case CAN traffic of one bus per cycle, and the refusal of a
//! configuration that cannot fit its cycle or exceeds a load limit.
//!
//! Every frame is counted at its worst-case stuffed length
//! ([`drivers::can::bit_timing::worst_case_bits`]): 55 bits for a SYNC without counter, 65 with
//! the counter byte or for a 1-byte heartbeat, 135 for an 8-byte frame. All arithmetic is integer
//! and rounds towards more load, so the budget never under-estimates.
//!
//! # What the worst cycle contains
//!
//! - **SYNC**: one per cycle (the cycle is SYNC-driven).
//! - **Synchronous PDOs** (transmission type 0, and 1..=240 "every n-th SYNC"): one frame each.
//!   Without phases the master controls, nothing keeps the n-th SYNCs of different PDOs apart,
//!   so some cycle carries them all; `1/n` only enters the *mean* load, which is reported for
//!   information and never used for admission.
//! - **Event-driven PDOs**: `ceil(cycle / min_interval)` frames, where `min_interval` is the
//!   inhibit time; without one the traffic has no bound and the configuration is refused.
//! - **Heartbeat** with period `p`: `ceil(cycle / p)` 1-byte frames; **node guarding** with
//!   guard time `g`: `ceil(cycle / g)` remote requests plus as many 1-byte answers. Phases are
//!   unknown, so every node's frame may land in the same cycle.
//! - **EMCY**: an allowance of 8-byte frames per cycle; **SDO**: reserved slots of one 8-byte
//!   request plus one 8-byte response each.
//!
//! Only `core` is used (no allocation, no floats), so the coordinator's no_std core can hold it.

use core::fmt;
use core::time::Duration;

use drivers::can::bit_timing::{MAX_BITRATE, MIN_BITRATE, worst_case_bits};

/// Worst-case bits of a SYNC frame without the counter byte.
pub const SYNC_BITS: u64 = worst_case_bits(false, 0) as u64;
/// Worst-case bits of a SYNC frame with the counter byte (0x1019 > 0).
pub const SYNC_COUNTER_BITS: u64 = worst_case_bits(false, 1) as u64;
/// Worst-case bits of an 8-byte frame (EMCY, SDO request or response).
pub const FULL_FRAME_BITS: u64 = worst_case_bits(false, 8) as u64;
/// Worst-case bits of a heartbeat, boot-up or guarding answer (1 data byte).
pub const STATE_FRAME_BITS: u64 = worst_case_bits(false, 1) as u64;
/// Worst-case bits of a node-guarding request (remote frame, no data bytes on the wire).
pub const GUARD_REQUEST_BITS: u64 = worst_case_bits(false, 0) as u64;
/// The highest "every n-th SYNC" transmission type of CiA 301.
pub const MAX_SYNC_EVERY: u8 = 240;

const NS_PER_S: u128 = 1_000_000_000;

/// A ratio in tenths of a percent; displayed as a percentage with one decimal ("107.5 %").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
pub struct Permille(pub u32);

impl Permille {
    /// A whole percentage (80 -> 80.0 %).
    pub const fn from_percent(percent: u32) -> Self {
        Self(percent.saturating_mul(10))
    }

    /// `num / den` in per-mille, rounded up; saturates instead of overflowing.
    fn ceil_ratio(num: u128, den: u128) -> Self {
        let v = num.saturating_mul(1000).div_ceil(den.max(1));
        Self(u32::try_from(v).unwrap_or(u32::MAX))
    }
}

impl fmt::Display for Permille {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{} %", self.0 / 10, self.0 % 10)
    }
}

/// When a PDO goes on the bus (the transmission type of its communication parameter).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trigger {
    /// Type 0: after a SYNC when its data changed; worst case after every SYNC.
    SyncAcyclic,
    /// Types 1..=240: after every n-th SYNC.
    SyncEvery(u8),
    /// Types 254/255 (or an RPDO the master sends on change): at most once per `min_interval`.
    Event {
        /// The shortest time between two transmissions (the inhibit time).
        min_interval: Duration,
    },
}

/// A transmission type the budget cannot account for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TransmissionTypeError {
    /// 241..=251 are reserved by CiA 301.
    #[error("transmission type {0} is reserved")]
    Reserved(u8),
    /// 252/253 (RTR-only) are not supported: CiA recommends against remote frames for PDOs.
    #[error("transmission type {0} (RTR-only) is not supported")]
    RemoteOnly(u8),
    /// 254/255 without an inhibit time: the drive may send without bound.
    #[error(
        "transmission type {0} is event-driven without an inhibit time, so its traffic has no bound"
    )]
    Unbounded(u8),
}

impl Trigger {
    /// The trigger of a CiA 301 transmission type; `inhibit` is the PDO's inhibit time (0x180x
    /// sub 3, in units of 100 us), which bounds event-driven types.
    pub fn from_transmission_type(
        transmission_type: u8,
        inhibit: Duration,
    ) -> Result<Self, TransmissionTypeError> {
        match transmission_type {
            0 => Ok(Self::SyncAcyclic),
            n @ 1..=MAX_SYNC_EVERY => Ok(Self::SyncEvery(n)),
            n @ 241..=251 => Err(TransmissionTypeError::Reserved(n)),
            n @ (252 | 253) => Err(TransmissionTypeError::RemoteOnly(n)),
            n if inhibit.is_zero() => Err(TransmissionTypeError::Unbounded(n)),
            _ => Ok(Self::Event {
                min_interval: inhibit,
            }),
        }
    }
}

/// One PDO on the bus: its data length and when it is sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pdo {
    /// Data bytes (0..=8).
    pub len: u8,
    /// When it goes on the bus.
    pub trigger: Trigger,
}

impl Pdo {
    /// A PDO sent after every SYNC (transmission type 1).
    pub const fn every_sync(len: u8) -> Self {
        Self {
            len,
            trigger: Trigger::SyncEvery(1),
        }
    }
}

/// How one node's liveness is supervised; the consumer side adds no traffic.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Supervision {
    /// No heartbeat, no guarding.
    None,
    /// The node produces a heartbeat every `period` (0x1017); zero disables it.
    Heartbeat {
        /// Producer heartbeat time.
        period: Duration,
    },
    /// The master guards the node every `guard_time` (0x100C); zero disables it.
    Guarding {
        /// Guard time.
        guard_time: Duration,
    },
}

/// Which PDO direction an error or a count refers to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PdoKind {
    /// Received by the drive, sent by the master.
    Rpdo,
    /// Sent by the drive.
    Tpdo,
}

impl fmt::Display for PdoKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Rpdo => "RPDO",
            Self::Tpdo => "TPDO",
        })
    }
}

/// One bus's cyclic traffic, as the configuration describes it. Borrowed slices keep it
/// allocation-free: the configuration owns the storage.
#[derive(Clone, Copy, Debug)]
pub struct BusTraffic<'a> {
    /// The bus's name, for messages ("can0").
    pub name: &'a str,
    /// Bitrate in bit/s.
    pub bitrate: u32,
    /// The SYNC period.
    pub cycle: Duration,
    /// Whether SYNC carries the counter byte.
    pub sync_counter: bool,
    /// The PDOs the master sends.
    pub rpdos: &'a [Pdo],
    /// The PDOs the drives send.
    pub tpdos: &'a [Pdo],
    /// Heartbeat or guarding, one entry per node.
    pub nodes: &'a [Supervision],
    /// 8-byte EMCY frames allowed for per cycle (all nodes together).
    pub emcy_per_cycle: u16,
    /// Reserved SDO slots per cycle, each an 8-byte request and an 8-byte response.
    pub sdo_slots: u16,
}

/// Frames and bits one category puts on the bus per cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Share {
    /// Frames in the worst cycle.
    pub frames: u64,
    /// Worst-case stuffed bits in the worst cycle.
    pub bits: u64,
    /// Mean bits per cycle over many cycles, in thousandths of a bit, rounded up.
    pub mean_millibits: u64,
}

impl Share {
    /// Adds `frames` frames of `bits` each in the worst cycle, and a mean of
    /// `bits * mean_num / mean_den` per cycle.
    fn add(&mut self, frames: u64, bits: u64, mean_num: u128, mean_den: u128) {
        self.frames = self.frames.saturating_add(frames);
        self.bits = self.bits.saturating_add(frames.saturating_mul(bits));
        let mean = (bits as u128)
            .saturating_mul(1000)
            .saturating_mul(mean_num)
            .div_ceil(mean_den.max(1));
        self.mean_millibits = self
            .mean_millibits
            .saturating_add(u64::try_from(mean).unwrap_or(u64::MAX));
    }
}

/// A configuration the budget refuses, with the numbers that explain why.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum BudgetError<'a> {
    /// The bitrate is outside classic CAN's range.
    #[error("bus {bus}: bitrate {bitrate} bit/s is outside {MIN_BITRATE}..={MAX_BITRATE}")]
    Bitrate {
        /// Bus name.
        bus: &'a str,
        /// The configured bitrate.
        bitrate: u32,
    },
    /// A zero cycle period carries nothing.
    #[error("bus {bus}: the cycle period is zero")]
    ZeroCycle {
        /// Bus name.
        bus: &'a str,
    },
    /// A PDO longer than a classic CAN frame.
    #[error("bus {bus}: {kind} {index} has {len} data bytes, more than 8")]
    PdoLength {
        /// Bus name.
        bus: &'a str,
        /// Direction.
        kind: PdoKind,
        /// Position in the configured list (0-based).
        index: usize,
        /// The configured length.
        len: u8,
    },
    /// "Every n-th SYNC" outside 1..=240.
    #[error("bus {bus}: {kind} {index} is sent every {every}. SYNC; CiA 301 allows 1..=240")]
    SyncEvery {
        /// Bus name.
        bus: &'a str,
        /// Direction.
        kind: PdoKind,
        /// Position in the configured list (0-based).
        index: usize,
        /// The configured divider.
        every: u8,
    },
    /// An event-driven PDO with a zero minimum interval has no bound.
    #[error(
        "bus {bus}: {kind} {index} is event-driven without an inhibit time, so its traffic has no bound"
    )]
    Unbounded {
        /// Bus name.
        bus: &'a str,
        /// Direction.
        kind: PdoKind,
        /// Position in the configured list (0-based).
        index: usize,
    },
    /// The worst cycle needs more bus time than the cycle has.
    #[error("{load}, does not fit the cycle")]
    DoesNotFit {
        /// The worst cycle's numbers.
        load: LoadSummary<'a>,
    },
    /// The worst cycle fits but exceeds the configured load limit.
    #[error("{load}, over the {limit} limit")]
    OverLimit {
        /// The worst cycle's numbers.
        load: LoadSummary<'a>,
        /// The configured limit.
        limit: Permille,
    },
}

/// The worst-case load of one bus per cycle, by category.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BusLoad<'a> {
    /// The bus's name.
    pub name: &'a str,
    /// Bitrate in bit/s.
    pub bitrate: u32,
    /// The SYNC period.
    pub cycle: Duration,
    /// SYNC frames.
    pub sync: Share,
    /// PDOs the master sends.
    pub rpdo: Share,
    /// PDOs the drives send.
    pub tpdo: Share,
    /// Heartbeat and node guarding.
    pub supervision: Share,
    /// EMCY allowance.
    pub emcy: Share,
    /// Reserved SDO slots.
    pub sdo: Share,
}

impl<'a> BusLoad<'a> {
    /// Validates `traffic` and computes its worst cycle.
    pub fn compute(traffic: &BusTraffic<'a>) -> Result<Self, BudgetError<'a>> {
        let bus = traffic.name;
        if !(MIN_BITRATE..=MAX_BITRATE).contains(&traffic.bitrate) {
            return Err(BudgetError::Bitrate {
                bus,
                bitrate: traffic.bitrate,
            });
        }
        if traffic.cycle.is_zero() {
            return Err(BudgetError::ZeroCycle { bus });
        }
        let cycle_ns = traffic.cycle.as_nanos();
        let mut load = Self {
            name: bus,
            bitrate: traffic.bitrate,
            cycle: traffic.cycle,
            sync: Share::default(),
            rpdo: Share::default(),
            tpdo: Share::default(),
            supervision: Share::default(),
            emcy: Share::default(),
            sdo: Share::default(),
        };

        let sync_bits = if traffic.sync_counter {
            SYNC_COUNTER_BITS
        } else {
            SYNC_BITS
        };
        load.sync.add(1, sync_bits, 1, 1);

        for (kind, pdos, share) in [
            (PdoKind::Rpdo, traffic.rpdos, &mut load.rpdo),
            (PdoKind::Tpdo, traffic.tpdos, &mut load.tpdo),
        ] {
            for (index, pdo) in pdos.iter().enumerate() {
                if pdo.len > 8 {
                    return Err(BudgetError::PdoLength {
                        bus,
                        kind,
                        index,
                        len: pdo.len,
                    });
                }
                let bits = worst_case_bits(false, pdo.len) as u64;
                match pdo.trigger {
                    Trigger::SyncAcyclic => share.add(1, bits, 1, 1),
                    Trigger::SyncEvery(every @ 1..=MAX_SYNC_EVERY) => {
                        share.add(1, bits, 1, every as u128)
                    }
                    Trigger::SyncEvery(every) => {
                        return Err(BudgetError::SyncEvery {
                            bus,
                            kind,
                            index,
                            every,
                        });
                    }
                    Trigger::Event { min_interval } if min_interval.is_zero() => {
                        return Err(BudgetError::Unbounded { bus, kind, index });
                    }
                    Trigger::Event { min_interval } => {
                        let every_ns = min_interval.as_nanos();
                        share.add(per_window(cycle_ns, every_ns), bits, cycle_ns, every_ns);
                    }
                }
            }
        }

        for node in traffic.nodes {
            match *node {
                Supervision::Heartbeat { period } if !period.is_zero() => {
                    let p = period.as_nanos();
                    load.supervision
                        .add(per_window(cycle_ns, p), STATE_FRAME_BITS, cycle_ns, p);
                }
                Supervision::Guarding { guard_time } if !guard_time.is_zero() => {
                    let g = guard_time.as_nanos();
                    let n = per_window(cycle_ns, g);
                    load.supervision.add(n, GUARD_REQUEST_BITS, cycle_ns, g);
                    load.supervision.add(n, STATE_FRAME_BITS, cycle_ns, g);
                }
                _ => {}
            }
        }

        let emcy = traffic.emcy_per_cycle as u64;
        load.emcy.add(emcy, FULL_FRAME_BITS, emcy as u128, 1);
        let sdo = 2 * traffic.sdo_slots as u64;
        load.sdo.add(sdo, FULL_FRAME_BITS, sdo as u128, 1);
        Ok(load)
    }

    /// The categories in report order, with their labels.
    pub fn categories(&self) -> [(&'static str, Share); 6] {
        [
            ("SYNC", self.sync),
            ("RPDO", self.rpdo),
            ("TPDO", self.tpdo),
            ("heartbeat/guarding", self.supervision),
            ("EMCY", self.emcy),
            ("SDO", self.sdo),
        ]
    }

    /// Frames in the worst cycle.
    pub fn frames(&self) -> u64 {
        self.categories()
            .iter()
            .fold(0u64, |a, (_, s)| a.saturating_add(s.frames))
    }

    /// Worst-case stuffed bits in the worst cycle.
    pub fn bits(&self) -> u64 {
        self.categories()
            .iter()
            .fold(0u64, |a, (_, s)| a.saturating_add(s.bits))
    }

    fn mean_millibits(&self) -> u64 {
        self.categories()
            .iter()
            .fold(0u64, |a, (_, s)| a.saturating_add(s.mean_millibits))
    }

    /// Bus time of the worst cycle in microseconds, rounded up.
    pub fn micros(&self) -> u64 {
        let us = (self.bits() as u128 * 1_000_000).div_ceil(self.bitrate.max(1) as u128);
        u64::try_from(us).unwrap_or(u64::MAX)
    }

    /// The cycle period in whole microseconds (rounded down: the message never overstates it).
    pub fn cycle_micros(&self) -> u64 {
        u64::try_from(self.cycle.as_micros()).unwrap_or(u64::MAX)
    }

    /// `bitrate * cycle`: the bits one cycle can carry, times 10^9 (kept exact).
    fn capacity_nanobits(&self) -> u128 {
        self.cycle.as_nanos().saturating_mul(self.bitrate as u128)
    }

    /// Whole bits one cycle can carry.
    pub fn capacity_bits(&self) -> u64 {
        u64::try_from(self.capacity_nanobits() / NS_PER_S).unwrap_or(u64::MAX)
    }

    /// The worst cycle's share of the cycle, rounded up.
    pub fn load(&self) -> Permille {
        Permille::ceil_ratio(
            (self.bits() as u128).saturating_mul(NS_PER_S),
            self.capacity_nanobits(),
        )
    }

    /// The mean share over many cycles (every n-th SYNC counted as 1/n), rounded up; for
    /// information only, admission uses [`load`](Self::load).
    pub fn mean_load(&self) -> Permille {
        Permille::ceil_ratio(
            (self.mean_millibits() as u128).saturating_mul(NS_PER_S / 1000),
            self.capacity_nanobits(),
        )
    }

    /// Whether the worst cycle fits in the cycle (exact, not via the rounded load).
    pub fn fits(&self) -> bool {
        (self.bits() as u128).saturating_mul(NS_PER_S) <= self.capacity_nanobits()
    }

    /// How many more 8-byte frames the worst cycle would still fit.
    pub fn spare_full_frames(&self) -> u64 {
        self.capacity_bits().saturating_sub(self.bits()) / FULL_FRAME_BITS
    }

    /// Refuses a worst cycle that does not fit the cycle or whose load exceeds `limit`.
    pub fn check(&self, limit: Permille) -> Result<(), BudgetError<'a>> {
        if !self.fits() {
            return Err(BudgetError::DoesNotFit {
                load: self.summary(),
            });
        }
        // Exact comparison: bits / capacity > limit / 1000.
        let used = (self.bits() as u128)
            .saturating_mul(NS_PER_S)
            .saturating_mul(1000);
        let allowed = self.capacity_nanobits().saturating_mul(limit.0 as u128);
        if used > allowed {
            return Err(BudgetError::OverLimit {
                load: self.summary(),
                limit,
            });
        }
        Ok(())
    }

    /// The numbers of the one-line summary the refusal messages start with:
    /// "bus can0: 9 frames, 975 us per 1000 us cycle = 97.5 %".
    pub fn summary(&self) -> LoadSummary<'a> {
        LoadSummary {
            bus: self.name,
            frames: self.frames(),
            bits: self.bits(),
            micros: self.micros(),
            cycle_micros: self.cycle_micros(),
            load: self.load(),
        }
    }
}

/// The worst cycle of one bus in a few numbers; small enough to travel inside an error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoadSummary<'a> {
    /// The bus's name.
    pub bus: &'a str,
    /// Frames in the worst cycle.
    pub frames: u64,
    /// Worst-case stuffed bits in the worst cycle.
    pub bits: u64,
    /// Bus time of the worst cycle in microseconds, rounded up.
    pub micros: u64,
    /// The cycle period in whole microseconds.
    pub cycle_micros: u64,
    /// The worst cycle's share of the cycle, rounded up.
    pub load: Permille,
}

impl fmt::Display for LoadSummary<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "bus {}: {} frames, {} us per {} us cycle = {}",
            self.bus, self.frames, self.micros, self.cycle_micros, self.load
        )
    }
}

/// The report `coordinator check` prints: the summary, then one line per category.
impl fmt::Display for BusLoad<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (mean {}", self.summary(), self.mean_load())?;
        if self.bitrate.is_multiple_of(1000) {
            write!(f, ", {} kbit/s", self.bitrate / 1000)?;
        } else {
            write!(f, ", {} bit/s", self.bitrate)?;
        }
        write!(
            f,
            ", room for {} more 8-byte frames)",
            self.spare_full_frames()
        )?;
        for (label, share) in self.categories() {
            write!(
                f,
                "\n  {label:<18} {:>4} frames {:>6} bits",
                share.frames, share.bits
            )?;
        }
        Ok(())
    }
}

/// Frames with at least `every_ns` between them that fit in a half-open window of `window_ns`:
/// `ceil(window / every)`.
fn per_window(window_ns: u128, every_ns: u128) -> u64 {
    u64::try_from(window_ns.div_ceil(every_ns.max(1))).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn bus<'a>(cycle: Duration, rpdos: &'a [Pdo], tpdos: &'a [Pdo]) -> BusTraffic<'a> {
        BusTraffic {
            name: "can0",
            bitrate: 1_000_000,
            cycle,
            sync_counter: false,
            rpdos,
            tpdos,
            nodes: &[],
            emcy_per_cycle: 0,
            sdo_slots: 0,
        }
    }

    const FOUR_AXES: [Pdo; 4] = [Pdo::every_sync(6); 4];

    #[test]
    fn frame_lengths() {
        assert_eq!(SYNC_BITS, 55);
        assert_eq!(SYNC_COUNTER_BITS, 65);
        assert_eq!(FULL_FRAME_BITS, 135);
        assert_eq!(STATE_FRAME_BITS, 65);
        let pdos = [Pdo::every_sync(6)];
        let l = BusLoad::compute(&bus(MS, &pdos, &[])).unwrap();
        assert_eq!(l.rpdo.bits, 115);
    }

    /// DESIGN.md: "at 1 Mbit/s a 1 ms cycle carries SYNC plus about 7 such frames": exactly 7.
    #[test]
    fn one_ms_at_one_mbit_carries_sync_plus_seven_full_frames() {
        let most = |sync_counter: bool| {
            (0..20)
                .take_while(|&n| {
                    let pdos = [Pdo::every_sync(8); 20];
                    let mut t = bus(MS, &pdos[..n], &[]);
                    t.sync_counter = sync_counter;
                    BusLoad::compute(&t).unwrap().fits()
                })
                .last()
                .unwrap()
        };
        assert_eq!(most(false), 7);
        // The counter byte costs 10 bits, and the seventh frame no longer fits.
        assert_eq!(most(true), 6);

        let pdos = [Pdo::every_sync(8); 7];
        let l = BusLoad::compute(&bus(MS, &pdos, &[])).unwrap();
        assert_eq!((l.frames(), l.bits(), l.micros()), (8, 1000, 1000));
        assert_eq!(l.load(), Permille(1000));
        assert_eq!(l.spare_full_frames(), 0);
        assert!(l.check(Permille(1000)).is_ok());
        assert!(l.check(Permille(999)).is_err());
    }

    #[test]
    fn four_axes_at_two_ms_fit_at_49_percent() {
        let l = BusLoad::compute(&bus(2 * MS, &FOUR_AXES, &FOUR_AXES)).unwrap();
        // SYNC 55 + 8 * 115 = 975 bits of 2000.
        assert_eq!((l.frames(), l.bits(), l.micros()), (9, 975, 975));
        assert_eq!(l.load(), Permille(488)); // 48.75 % rounded up
        assert_eq!(l.mean_load(), Permille(488));
        assert_eq!(l.spare_full_frames(), 7);
        assert!(l.check(Permille::from_percent(80)).is_ok());
    }

    #[test]
    fn four_axes_at_one_ms_exceed_95_percent() {
        let l = BusLoad::compute(&bus(MS, &FOUR_AXES, &FOUR_AXES)).unwrap();
        assert!(l.fits());
        assert_eq!(l.load(), Permille(975));
        let limit = Permille::from_percent(95);
        assert_eq!(
            l.check(limit),
            Err(BudgetError::OverLimit {
                load: l.summary(),
                limit
            })
        );
        assert!(l.check(Permille(975)).is_ok());
    }

    #[test]
    fn refusal_messages_carry_the_numbers() {
        let l = BusLoad::compute(&bus(MS, &FOUR_AXES, &FOUR_AXES)).unwrap();
        let e = l.check(Permille::from_percent(80)).unwrap_err();
        let BudgetError::OverLimit { load, limit } = e else {
            panic!("{e:?}")
        };
        assert_eq!(
            (load.frames, load.bits, load.micros, load.cycle_micros),
            (9, 975, 975, 1000)
        );
        assert_eq!((load.load, limit), (Permille(975), Permille(800)));
        assert_eq!(
            e.to_string(),
            "bus can0: 9 frames, 975 us per 1000 us cycle = 97.5 %, over the 80.0 % limit"
        );

        let mut t = bus(MS, &FOUR_AXES, &FOUR_AXES);
        t.sdo_slots = 1;
        t.bitrate = 500_000;
        let l = BusLoad::compute(&t).unwrap();
        // (975 + 270) bits at 2 us each.
        assert_eq!(
            l.check(Permille::from_percent(80)).unwrap_err().to_string(),
            "bus can0: 11 frames, 2490 us per 1000 us cycle = 249.0 %, does not fit the cycle"
        );
    }

    #[test]
    fn rounding_never_underestimates() {
        let pdos = [Pdo::every_sync(3), Pdo::every_sync(7), Pdo::every_sync(5)];
        for bitrate in [
            20_000, 33_333, 125_000, 333_333, 500_000, 777_777, 1_000_000,
        ] {
            for cycle_us in [250u64, 999, 1000, 1234, 3333, 10_000] {
                let mut t = bus(Duration::from_micros(cycle_us), &pdos, &pdos);
                t.bitrate = bitrate;
                t.sync_counter = cycle_us % 2 == 1;
                let l = BusLoad::compute(&t).unwrap();
                let bits = l.bits() as u128;
                let us = l.micros() as u128;
                // micros is the least whole number not below the exact bus time.
                assert!(us * bitrate as u128 >= bits * 1_000_000);
                assert!((us - 1) * (bitrate as u128) < bits * 1_000_000);
                // load is the least whole per-mille not below the exact ratio.
                let capacity = cycle_us as u128 * bitrate as u128; // * 10^-6 bits
                let p = l.load().0 as u128;
                assert!(p * capacity >= bits * 1_000_000_000);
                assert!((p - 1) * capacity < bits * 1_000_000_000);
                assert_eq!(l.fits(), bits * 1_000_000 <= capacity);
                assert!(l.capacity_bits() as u128 * 1_000_000 <= capacity);
            }
        }
    }

    #[test]
    fn transmission_type_n_counts_fully_in_the_worst_cycle() {
        assert_eq!(
            Trigger::from_transmission_type(4, Duration::ZERO),
            Ok(Trigger::SyncEvery(4))
        );
        assert_eq!(
            Trigger::from_transmission_type(0, Duration::ZERO),
            Ok(Trigger::SyncAcyclic)
        );
        assert_eq!(
            Trigger::from_transmission_type(245, Duration::ZERO),
            Err(TransmissionTypeError::Reserved(245))
        );
        assert_eq!(
            Trigger::from_transmission_type(252, Duration::ZERO),
            Err(TransmissionTypeError::RemoteOnly(252))
        );
        assert_eq!(
            Trigger::from_transmission_type(255, Duration::ZERO),
            Err(TransmissionTypeError::Unbounded(255))
        );
        assert_eq!(
            Trigger::from_transmission_type(254, Duration::from_micros(300)),
            Ok(Trigger::Event {
                min_interval: Duration::from_micros(300)
            })
        );

        let every_4th = [Pdo {
            len: 8,
            trigger: Trigger::SyncEvery(4),
        }; 4];
        let l = BusLoad::compute(&bus(MS, &[], &every_4th)).unwrap();
        // The cycle in which all four coincide carries all four.
        assert_eq!((l.tpdo.frames, l.tpdo.bits), (4, 540));
        // On average one of them per cycle.
        assert_eq!(l.tpdo.mean_millibits, 135_000);
        assert_eq!(l.load(), Permille(595));
        assert_eq!(l.mean_load(), Permille(190));

        // 1/3 of 115 bits = 38.33.. rounds up.
        let third = [Pdo {
            len: 6,
            trigger: Trigger::SyncEvery(3),
        }];
        let l = BusLoad::compute(&bus(MS, &[], &third)).unwrap();
        assert_eq!(l.tpdo.mean_millibits, 38_334);

        let zero = [Pdo {
            len: 8,
            trigger: Trigger::SyncEvery(0),
        }];
        assert_eq!(
            BusLoad::compute(&bus(MS, &zero, &[])),
            Err(BudgetError::SyncEvery {
                bus: "can0",
                kind: PdoKind::Rpdo,
                index: 0,
                every: 0
            })
        );
    }

    #[test]
    fn event_driven_pdos_are_bounded_by_their_inhibit_time() {
        let ev = |us| Pdo {
            len: 2,
            trigger: Trigger::Event {
                min_interval: Duration::from_micros(us),
            },
        };
        // 1000 / 300 -> 4 frames can start within one cycle.
        let pdos = [ev(300)];
        let l = BusLoad::compute(&bus(MS, &[], &pdos)).unwrap();
        assert_eq!((l.tpdo.frames, l.tpdo.bits), (4, 4 * 75));
        // Exactly a divisor: 2 frames, not 3.
        let pdos = [ev(500)];
        let l = BusLoad::compute(&bus(MS, &[], &pdos)).unwrap();
        assert_eq!(l.tpdo.frames, 2);
        // Longer than the cycle: still one in the worst cycle.
        let pdos = [ev(10_000)];
        let l = BusLoad::compute(&bus(MS, &[], &pdos)).unwrap();
        assert_eq!(l.tpdo.frames, 1);
        assert_eq!(l.tpdo.mean_millibits, 7_500);
        assert_eq!(
            BusLoad::compute(&bus(MS, &[ev(100), ev(0)], &[])),
            Err(BudgetError::Unbounded {
                bus: "can0",
                kind: PdoKind::Rpdo,
                index: 1
            })
        );
    }

    #[test]
    fn heartbeat_and_guarding_count_in_the_worst_cycle() {
        let nodes = [
            Supervision::Heartbeat {
                period: Duration::from_millis(100),
            },
            Supervision::Heartbeat {
                period: Duration::from_micros(300),
            },
            Supervision::Guarding {
                guard_time: Duration::from_millis(50),
            },
            Supervision::Heartbeat {
                period: Duration::ZERO,
            },
            Supervision::Guarding {
                guard_time: Duration::ZERO,
            },
            Supervision::None,
        ];
        let mut t = bus(MS, &[], &[]);
        t.nodes = &nodes;
        let l = BusLoad::compute(&t).unwrap();
        // 1 + ceil(1000/300) = 4 heartbeats, then one request + one answer of guarding.
        assert_eq!(l.supervision.frames, 1 + 4 + 2);
        assert_eq!(l.supervision.bits, 5 * 65 + 55 + 65);
        // Mean: 65/100 + 65*10/3 + 120/50 bits per cycle, in millibits rounded up per node.
        assert_eq!(l.supervision.mean_millibits, 650 + 216_667 + 1_100 + 1_300);
        assert_eq!(l.frames(), 1 + 7);
    }

    #[test]
    fn emcy_and_sdo_allowances() {
        let mut t = bus(MS, &[], &[]);
        t.emcy_per_cycle = 2;
        t.sdo_slots = 1;
        let l = BusLoad::compute(&t).unwrap();
        assert_eq!((l.emcy.frames, l.emcy.bits), (2, 270));
        assert_eq!((l.sdo.frames, l.sdo.bits), (2, 270));
        assert_eq!(l.bits(), 55 + 540);
        assert_eq!(l.emcy.mean_millibits + l.sdo.mean_millibits, 540_000);
        assert_eq!(l.mean_load(), l.load());
    }

    #[test]
    fn inconsistent_settings_are_refused() {
        let mut t = bus(MS, &[], &[]);
        t.bitrate = 10_000;
        assert_eq!(
            BusLoad::compute(&t).unwrap_err().to_string(),
            "bus can0: bitrate 10000 bit/s is outside 20000..=1000000"
        );
        let t = bus(Duration::ZERO, &[], &[]);
        assert_eq!(
            BusLoad::compute(&t),
            Err(BudgetError::ZeroCycle { bus: "can0" })
        );
        let long = [Pdo::every_sync(8), Pdo::every_sync(9)];
        assert_eq!(
            BusLoad::compute(&bus(MS, &[], &long))
                .unwrap_err()
                .to_string(),
            "bus can0: TPDO 1 has 9 data bytes, more than 8"
        );
    }

    #[test]
    fn report_lists_every_category() {
        let mut t = bus(2 * MS, &FOUR_AXES, &FOUR_AXES);
        t.sdo_slots = 1;
        let report = BusLoad::compute(&t).unwrap().to_string();
        let lines: Vec<&str> = report.lines().collect();
        assert_eq!(
            lines[0],
            "bus can0: 11 frames, 1245 us per 2000 us cycle = 62.3 % \
             (mean 62.3 %, 1000 kbit/s, room for 5 more 8-byte frames)"
        );
        assert_eq!(lines[1], "  SYNC                  1 frames     55 bits");
        assert_eq!(lines[2], "  RPDO                  4 frames    460 bits");
        assert_eq!(lines[6], "  SDO                   2 frames    270 bits");
        assert_eq!(lines.len(), 7);
    }
}
