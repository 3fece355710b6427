//! Fault injection rules for the virtual bus.
//!
//! A [`FaultRule`] selects frames by identifier ([`IdMatch`]), optionally by a time window
//! ([`TimeWindow`], on the frame's completion time) and optionally by a probability drawn from
//! its own seeded ChaCha8 generator, and applies one [`FaultAction`] to the selected frames: drop,
//! delay, corrupt or duplicate. A [`FaultSet`] holds the rules of one bus and turns a completed
//! frame into a [`FaultOutcome`]; it is pure (no clock, no I/O), so it is tested on its own.
//!
//! Each rule owns its generator, seeded by the caller: adding or removing another rule does not
//! change which frames a probabilistic rule hits, and the same run repeats exactly.
//!
//! Port-level faults (node disconnect, bus-off for a time window) are not rules: they belong to a
//! port and are set on the bus ([`super::VirtualBus::set_disconnected`],
//! [`super::VirtualBus::set_bus_off`]).

use super::Frame;
use crate::time::Instant;
use core::time::Duration;
use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Which identifiers a rule selects, compared with [`Frame::raw_id`] (11 or 29 bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IdMatch {
    /// Every frame.
    Any,
    /// Exactly this identifier.
    Exact(u32),
    /// Identifiers whose bits under `mask` equal those of `id` (an acceptance filter).
    Mask {
        /// The identifier bits to compare.
        id: u32,
        /// Which bits take part in the comparison.
        mask: u32,
    },
}

impl IdMatch {
    /// Whether `raw_id` is selected.
    pub fn matches(&self, raw_id: u32) -> bool {
        match *self {
            IdMatch::Any => true,
            IdMatch::Exact(id) => raw_id == id,
            IdMatch::Mask { id, mask } => raw_id & mask == id & mask,
        }
    }
}

/// A half-open time window `[from, until)` in the bus clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeWindow {
    /// First instant inside the window.
    pub from: Instant,
    /// First instant after the window.
    pub until: Instant,
}

impl TimeWindow {
    /// The window `[from, until)`.
    pub const fn new(from: Instant, until: Instant) -> Self {
        TimeWindow { from, until }
    }
    /// Whether `t` lies inside the window.
    pub fn contains(&self, t: Instant) -> bool {
        self.from <= t && t < self.until
    }
    /// Whether the window overlaps the closed interval `[a, b]`.
    pub fn overlaps(&self, a: Instant, b: Instant) -> bool {
        self.from <= b && a < self.until
    }
}

/// What a rule does to the frames it selects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultAction {
    /// No receiver gets the frame (it still occupied the bus).
    Drop,
    /// Receivers get the frame this much later than it completed, with that later timestamp.
    Delay(Duration),
    /// Receivers get the frame with its data bytes xor-ed with this pattern (byte `i` with
    /// `xor[i]`); frames without data bytes are unchanged.
    Corrupt {
        /// The pattern xor-ed into the data bytes.
        xor: [u8; 8],
    },
    /// The frame is transmitted twice, back to back (as after an error in the last bit of the
    /// end-of-frame field): receivers get two copies, the second one frame-time later.
    Duplicate,
}

/// Selection by chance: the rule fires with probability `p`, drawn from ChaCha8 seeded by `seed`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Probability {
    /// Probability of firing, 0.0..=1.0 (values outside are clamped, NaN counts as 0).
    pub p: f64,
    /// Seed of the rule's own generator.
    pub seed: u64,
}

/// One fault injection rule: a selection and an action.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultRule {
    /// Which identifiers are selected.
    pub ids: IdMatch,
    /// Only frames completing inside this window are selected; `None` for always.
    pub window: Option<TimeWindow>,
    /// Only a random share of the otherwise selected frames; `None` for all of them.
    pub probability: Option<Probability>,
    /// What happens to selected frames.
    pub action: FaultAction,
}

impl FaultRule {
    /// A rule applying `action` to every frame matching `ids`.
    pub const fn new(ids: IdMatch, action: FaultAction) -> Self {
        FaultRule {
            ids,
            window: None,
            probability: None,
            action,
        }
    }
    /// Drops frames matching `ids`.
    pub const fn drop(ids: IdMatch) -> Self {
        Self::new(ids, FaultAction::Drop)
    }
    /// Delays frames matching `ids` by `by`.
    pub const fn delay(ids: IdMatch, by: Duration) -> Self {
        Self::new(ids, FaultAction::Delay(by))
    }
    /// Corrupts frames matching `ids` by xor-ing `xor` into their data.
    pub const fn corrupt(ids: IdMatch, xor: [u8; 8]) -> Self {
        Self::new(ids, FaultAction::Corrupt { xor })
    }
    /// Duplicates frames matching `ids`.
    pub const fn duplicate(ids: IdMatch) -> Self {
        Self::new(ids, FaultAction::Duplicate)
    }
    /// Restricts the rule to frames completing inside `window`.
    pub const fn during(mut self, window: TimeWindow) -> Self {
        self.window = Some(window);
        self
    }
    /// Restricts the rule to a random share `p` of the selected frames, repeatably from `seed`.
    pub const fn with_probability(mut self, p: f64, seed: u64) -> Self {
        self.probability = Some(Probability { p, seed });
        self
    }
}

/// Handle of a rule in a [`FaultSet`], for removing it or reading its hit count.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct FaultId(pub u32);

/// The combined effect of all rules on one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FaultOutcome {
    /// No receiver gets the frame.
    pub drop: bool,
    /// Total delay of delivery (delays of several rules add up).
    pub delay: Duration,
    /// Pattern xor-ed into the data (patterns of several rules combine), if any rule corrupts.
    pub xor: Option<[u8; 8]>,
    /// The frame is transmitted a second time.
    pub duplicate: bool,
}

impl FaultOutcome {
    /// Whether no rule fired.
    pub fn is_clean(&self) -> bool {
        *self == FaultOutcome::default()
    }
    /// `frame` as receivers see it: data xor-ed with the corruption pattern.
    pub fn corrupted(&self, mut frame: Frame) -> Frame {
        if let Some(x) = self.xor {
            for (b, p) in frame.data_mut().iter_mut().zip(x) {
                *b ^= p;
            }
        }
        frame
    }
}

#[derive(Debug, Clone)]
struct ActiveRule {
    id: FaultId,
    rule: FaultRule,
    /// Threshold on a 53-bit uniform draw; `None` when the rule has no probability.
    threshold: Option<u64>,
    rng: ChaCha8Rng,
    hits: u64,
}

/// The rules of one bus, evaluated in the order they were added.
#[derive(Debug, Clone, Default)]
pub struct FaultSet {
    rules: Vec<ActiveRule>,
    next_id: u32,
}

/// A draw is 53 random bits, so a probability maps exactly onto an integer threshold.
const DRAW_BITS: u32 = 53;

fn threshold(p: f64) -> u64 {
    let p = if p.is_nan() { 0.0 } else { p.clamp(0.0, 1.0) };
    // p = 1 gives 2^53, above every 53-bit draw: always fires; p = 0 never does.
    (p * (1u64 << DRAW_BITS) as f64) as u64
}

impl FaultSet {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a rule, evaluated after the ones already present.
    pub fn add(&mut self, rule: FaultRule) -> FaultId {
        let id = FaultId(self.next_id);
        self.next_id = self.next_id.wrapping_add(1);
        let (threshold, seed) = match rule.probability {
            Some(p) => (Some(threshold(p.p)), p.seed),
            None => (None, 0),
        };
        self.rules.push(ActiveRule {
            id,
            rule,
            threshold,
            rng: ChaCha8Rng::seed_from_u64(seed),
            hits: 0,
        });
        id
    }

    /// Removes a rule; `false` if it was not present.
    pub fn remove(&mut self, id: FaultId) -> bool {
        let before = self.rules.len();
        self.rules.retain(|r| r.id != id);
        self.rules.len() != before
    }

    /// Removes every rule.
    pub fn clear(&mut self) {
        self.rules.clear();
    }

    /// Whether there are no rules (the bus skips evaluation then).
    pub fn is_empty(&self) -> bool {
        self.rules.is_empty()
    }

    /// How many frames a rule has hit so far; `None` if it is not present.
    pub fn hits(&self, id: FaultId) -> Option<u64> {
        self.rules.iter().find(|r| r.id == id).map(|r| r.hits)
    }

    /// Evaluates every rule for `frame` completing at `at`. A probabilistic rule draws from its
    /// generator only when its identifier and window select the frame, so its sequence of hits
    /// depends only on the frames it could apply to.
    pub fn evaluate(&mut self, frame: &Frame, at: Instant) -> FaultOutcome {
        let mut out = FaultOutcome::default();
        let raw = frame.raw_id();
        for r in &mut self.rules {
            if !r.rule.ids.matches(raw) {
                continue;
            }
            if let Some(w) = r.rule.window
                && !w.contains(at)
            {
                continue;
            }
            if let Some(t) = r.threshold {
                let draw = r.rng.next_u64() >> (64 - DRAW_BITS);
                if draw >= t {
                    continue;
                }
            }
            r.hits += 1;
            match r.rule.action {
                FaultAction::Drop => out.drop = true,
                FaultAction::Delay(d) => out.delay = out.delay.saturating_add(d),
                FaultAction::Corrupt { xor } => {
                    let mut acc = out.xor.unwrap_or([0; 8]);
                    for (a, x) in acc.iter_mut().zip(xor) {
                        *a ^= x;
                    }
                    out.xor = Some(acc);
                }
                FaultAction::Duplicate => out.duplicate = true,
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(id: u16) -> Frame {
        Frame::std8(id, [1, 2, 3, 4, 5, 6, 7, 8])
    }

    #[test]
    fn id_matching() {
        assert!(IdMatch::Any.matches(0x7FF));
        assert!(IdMatch::Exact(0x181).matches(0x181));
        assert!(!IdMatch::Exact(0x181).matches(0x182));
        // Every TPDO1 (0x181..0x1FF): function code bits compared, node bits ignored.
        let tpdo1 = IdMatch::Mask {
            id: 0x180,
            mask: 0x780,
        };
        assert!(tpdo1.matches(0x181) && tpdo1.matches(0x1FF));
        assert!(!tpdo1.matches(0x201));
    }

    #[test]
    fn window_is_half_open() {
        let w = TimeWindow::new(Instant::from_micros(10), Instant::from_micros(20));
        assert!(!w.contains(Instant::from_micros(9)));
        assert!(w.contains(Instant::from_micros(10)));
        assert!(!w.contains(Instant::from_micros(20)));
    }

    #[test]
    fn rules_combine_and_count_hits() {
        let mut set = FaultSet::new();
        let a = set.add(FaultRule::corrupt(
            IdMatch::Exact(0x181),
            [0xFF, 0, 0, 0, 0, 0, 0, 0],
        ));
        let b = set.add(FaultRule::delay(IdMatch::Any, Duration::from_micros(5)));
        let c = set.add(FaultRule::delay(IdMatch::Any, Duration::from_micros(7)));
        let out = set.evaluate(&f(0x181), Instant::ZERO);
        assert_eq!(out.delay, Duration::from_micros(12));
        assert_eq!(out.corrupted(f(0x181)).data()[0], 0xFE);
        let out = set.evaluate(&f(0x182), Instant::ZERO);
        assert_eq!(out.xor, None);
        assert_eq!(set.hits(a), Some(1));
        assert_eq!(set.hits(b), Some(2));
        assert!(set.remove(c));
        assert!(!set.remove(c));
        assert_eq!(set.hits(c), None);
        assert_eq!(
            set.evaluate(&f(0x182), Instant::ZERO).delay,
            Duration::from_micros(5)
        );
    }

    #[test]
    fn probability_repeats_with_seed_and_respects_extremes() {
        let run = |seed| {
            let mut set = FaultSet::new();
            let id = set.add(FaultRule::drop(IdMatch::Any).with_probability(0.3, seed));
            for _ in 0..10_000 {
                set.evaluate(&f(1), Instant::ZERO);
            }
            set.hits(id).unwrap_or(0)
        };
        let a = run(42);
        assert_eq!(a, run(42));
        assert!((2_500..3_500).contains(&a), "{a}");
        assert_ne!(a, run(43));

        let mut set = FaultSet::new();
        let never = set.add(FaultRule::drop(IdMatch::Any).with_probability(0.0, 1));
        let always = set.add(FaultRule::drop(IdMatch::Any).with_probability(1.0, 1));
        let nan = set.add(FaultRule::drop(IdMatch::Any).with_probability(f64::NAN, 1));
        for _ in 0..1000 {
            set.evaluate(&f(1), Instant::ZERO);
        }
        assert_eq!(set.hits(never), Some(0));
        assert_eq!(set.hits(always), Some(1000));
        assert_eq!(set.hits(nan), Some(0));
    }

    #[test]
    fn corrupt_leaves_empty_frames_alone() {
        let out = FaultOutcome {
            xor: Some([0xFF; 8]),
            ..FaultOutcome::default()
        };
        let empty = Frame::new_std(0x80, &[]).unwrap();
        assert_eq!(out.corrupted(empty), empty);
        let two = Frame::new_std(0x80, &[0x0F, 0xF0]).unwrap();
        assert_eq!(out.corrupted(two).data(), &[0xF0, 0x0F]);
    }
}
