//! The homing executor: runs a homing method description on an [`Axis`] and sets the
//! reference at the end.
//!
//! A method is described by what it references to ([`Reference`]) and whether the first
//! index pulse after that is the reference point; [`HomingMethod::from_number`] maps the
//! CiA 402 numbers (1, 2, 7, 11, 17, 18, 23, 27, 33, 34, 35, 37) and the Festo FHPP ones
//! (-17, -18, -35) onto descriptions. The sequence follows the digests: search at search
//! velocity, creep back at crawl velocity until the switch releases (that edge, or the next
//! index pulse, is the reference point REF), optionally travel to AZ = REF + offset, and give
//! AZ the home position value. Stop methods detect the stop as "pushing at the homing current
//! limit for the stop time" and always travel to AZ.

use core::time::Duration;

use super::axis::{Axis, Direction, SwitchZone, Switches};
use crate::time::Instant;

/// What a homing method references to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reference {
    /// The position the axis is at (CiA 402 35/37, Festo -35).
    CurrentPosition,
    /// A mechanical stop in this direction (Festo -17 negative, -18 positive).
    FixedStop(Direction),
    /// The limit switch on this side: run onto it, creep back until it releases.
    LimitSwitch(Direction),
    /// The reference switch, first searched in this direction: run onto it, creep back until
    /// it releases (if the axis starts on it, it creeps off it at once).
    ReferenceSwitch(Direction),
    /// The first index pulse in this direction (CiA 402 33 negative, 34 positive).
    IndexPulse(Direction),
}

/// A homing method description.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HomingMethod {
    /// What the method references to.
    pub reference: Reference,
    /// After the switch edge, creep on to the first index pulse; that pulse is REF.
    pub index: bool,
}

impl HomingMethod {
    /// The description of a CiA 402 (6098h) or Festo (PNU 1011) method number, `None` for a
    /// number this simulator does not run. The numbers are those of
    /// [`cia402::homing::HomingMethod`](crate::cia402::homing::HomingMethod), the crate's one
    /// table of them (23/27 follow CiA 402, 23 = positive; the CMMO-ST manual's table
    /// contradicts itself there).
    pub const fn from_number(method: i8) -> Option<Self> {
        match crate::cia402::homing::HomingMethod::from_code(method) {
            Ok(m) => Some(Self::from_plan(m.plan())),
            Err(_) => None,
        }
    }

    /// The description of a method given as data (which signal, which way, index or not).
    pub const fn from_plan(plan: crate::cia402::homing::HomingPlan) -> Self {
        use crate::cia402::homing::HomeSignal as S;
        let search = plan.search;
        let (reference, index) = match plan.signal {
            S::CurrentPosition => (Reference::CurrentPosition, false),
            S::HardStop => (Reference::FixedStop(search), false),
            // The pulse itself is the reference: no switch edge precedes it.
            S::IndexPulse => (Reference::IndexPulse(search), false),
            S::NegativeLimit => (
                Reference::LimitSwitch(Direction::Negative),
                plan.index_pulse,
            ),
            S::PositiveLimit => (
                Reference::LimitSwitch(Direction::Positive),
                plan.index_pulse,
            ),
            S::HomeSwitch => (Reference::ReferenceSwitch(search), plan.index_pulse),
        };
        HomingMethod { reference, index }
    }
}

impl From<crate::cia402::homing::HomingMethod> for HomingMethod {
    fn from(m: crate::cia402::homing::HomingMethod) -> Self {
        Self::from_plan(m.plan())
    }
}

/// Speeds, offsets and stop detection for a homing run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HomingParams {
    /// Search velocity, inc/s (6099h/1, PNU 1012/1).
    pub search_velocity: u32,
    /// Crawl (creep) velocity off the switch and to the index, inc/s.
    pub crawl_velocity: u32,
    /// Velocity of the travel to AZ, inc/s.
    pub travel_velocity: u32,
    /// Acceleration and deceleration, inc/s².
    pub acceleration: u32,
    /// AZ = REF + offset, increments.
    pub offset: i64,
    /// Travel to AZ at the end (stop methods always do).
    pub travel_to_offset: bool,
    /// The position value AZ gets.
    pub home_position: i64,
    /// Current limit while searching a stop, mA (Festo PNU 1015).
    pub stop_current_ma: u32,
    /// Pushing at that limit this long means "stop found" (also how a search that ran into
    /// the end of travel is noticed).
    pub stop_time: Duration,
    /// Longest search distance, increments; `None` = the travel range (and 2^30 without one).
    pub max_search: Option<u32>,
}

/// What was searched and not found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Searched {
    /// The reference switch.
    ReferenceSwitch,
    /// A limit switch.
    LimitSwitch(Direction),
    /// A mechanical stop.
    FixedStop(Direction),
    /// An index pulse.
    IndexPulse,
}

/// Why homing failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum HomingError {
    /// The search ended (end of travel, a limit switch in the way, or the search distance)
    /// without finding what it looked for.
    #[error("{searched:?} not found after {travelled} inc")]
    NotFound {
        /// What was searched.
        searched: Searched,
        /// How far the axis travelled, increments.
        travelled: u64,
    },
    /// The power stage went off or a following error occurred during homing.
    #[error("homing aborted: {reason:?}")]
    Aborted {
        /// What stopped it.
        reason: AbortReason,
    },
    /// The axis refused a command (e.g. a zero velocity in the parameters).
    #[error("the axis refused a homing command: {0}")]
    Command(#[from] super::axis::AxisError),
}

/// Why a homing run was aborted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AbortReason {
    /// The power stage is off.
    Disabled,
    /// A following error.
    FollowingError,
}

/// Progress of a homing run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HomingState {
    /// Still running.
    Running,
    /// Referenced: REF was at this raw position; AZ now reads the home position.
    Done {
        /// REF, raw increments.
        reference_raw: i64,
    },
    /// Failed; the axis was stopped. A previous reference is kept.
    Failed(HomingError),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Start,
    Search {
        dir: Direction,
    },
    Leave {
        dir: Direction,
    },
    Index {
        dir: Direction,
    },
    StopSearch {
        dir: Direction,
        pushing_since: Option<Instant>,
    },
    Stopping {
        reference: i64,
    },
    Travel {
        reference: i64,
    },
    Finished(HomingState),
}

/// Runs one homing method on an axis: call [`Homing::update`] after every [`Axis::step`].
#[derive(Debug, Clone, Copy)]
pub struct Homing {
    method: HomingMethod,
    params: HomingParams,
    phase: Phase,
    start_raw: i64,
    blocked_since: Option<Instant>,
}

impl Homing {
    /// A homing run, not started yet.
    pub const fn new(method: HomingMethod, params: HomingParams) -> Self {
        Homing {
            method,
            params,
            phase: Phase::Start,
            start_raw: 0,
            blocked_since: None,
        }
    }

    /// The current state.
    pub fn state(&self) -> HomingState {
        match self.phase {
            Phase::Finished(s) => s,
            _ => HomingState::Running,
        }
    }

    fn max_search(&self, axis: &Axis) -> u64 {
        match (self.params.max_search, axis.config().environment.travel) {
            (Some(m), _) => m as u64,
            (None, Some((a, b))) => a.abs_diff(b),
            (None, None) => 1 << 30,
        }
    }

    fn zone(axis: &Axis, r: Reference) -> Option<(Switches, Option<SwitchZone>)> {
        let env = &axis.config().environment;
        match r {
            Reference::ReferenceSwitch(_) => Some((Switches::REFERENCE, env.reference)),
            Reference::LimitSwitch(Direction::Negative) => {
                Some((Switches::LIMIT_NEGATIVE, env.limit_negative))
            }
            Reference::LimitSwitch(Direction::Positive) => {
                Some((Switches::LIMIT_POSITIVE, env.limit_positive))
            }
            _ => None,
        }
    }

    fn searched(&self) -> Searched {
        match self.method.reference {
            Reference::ReferenceSwitch(_) => Searched::ReferenceSwitch,
            Reference::LimitSwitch(d) => Searched::LimitSwitch(d),
            Reference::FixedStop(d) => Searched::FixedStop(d),
            Reference::IndexPulse(_) | Reference::CurrentPosition => Searched::IndexPulse,
        }
    }

    fn finish(&mut self, axis: &mut Axis, state: HomingState) -> HomingState {
        axis.set_current_limit(None);
        axis.set_following_error_monitoring(true);
        axis.set_limit_switch_stop(axis.config().stop_on_limit_switch);
        if let HomingState::Failed(_) = state {
            axis.hold();
        }
        self.phase = Phase::Finished(state);
        state
    }

    fn fail(&mut self, axis: &mut Axis, e: HomingError) -> HomingState {
        self.finish(axis, HomingState::Failed(e))
    }

    fn jog(&self, axis: &mut Axis, dir: Direction, v: u32) -> Result<(), HomingError> {
        let a = self.params.acceleration;
        axis.run_velocity(v.min(i32::MAX as u32) as i32 * dir.sign(), a, a)?;
        Ok(())
    }

    /// The reference point is known: stop, then travel to AZ or set the reference.
    fn found(&mut self, axis: &mut Axis, reference: i64) {
        axis.hold();
        self.phase = Phase::Stopping { reference };
    }

    /// Starts the run (if not started) and advances it by what the last axis step showed.
    pub fn update(&mut self, axis: &mut Axis) -> HomingState {
        match self.advance(axis) {
            Ok(s) => s,
            Err(e) => self.fail(axis, e),
        }
    }

    fn advance(&mut self, axis: &mut Axis) -> Result<HomingState, HomingError> {
        let st = *axis.status();
        if let Phase::Finished(s) = self.phase {
            return Ok(s);
        }
        if !axis.is_enabled() {
            return Err(HomingError::Aborted {
                reason: AbortReason::Disabled,
            });
        }
        if self.phase != Phase::Start && st.faults.contains(super::axis::Faults::FOLLOWING_ERROR) {
            return Err(HomingError::Aborted {
                reason: AbortReason::FollowingError,
            });
        }
        let raw = axis.raw_position();
        let travelled = raw.abs_diff(self.start_raw);
        let p = self.params;
        match self.phase {
            Phase::Start => {
                self.start_raw = raw;
                axis.set_limit_switch_stop(false);
                match self.method.reference {
                    Reference::CurrentPosition => self.found(axis, raw),
                    Reference::FixedStop(dir) => {
                        axis.set_current_limit(Some(p.stop_current_ma));
                        axis.set_following_error_monitoring(false);
                        self.jog(axis, dir, p.search_velocity)?;
                        self.phase = Phase::StopSearch {
                            dir,
                            pushing_since: None,
                        };
                    }
                    Reference::IndexPulse(dir) => {
                        axis.arm_index_latch();
                        self.jog(axis, dir, p.crawl_velocity)?;
                        self.phase = Phase::Index { dir };
                    }
                    r @ (Reference::ReferenceSwitch(dir) | Reference::LimitSwitch(dir)) => {
                        let on = Self::zone(axis, r).is_some_and(|(s, _)| st.switches.contains(s));
                        if on {
                            self.jog(axis, dir.reverse(), p.crawl_velocity)?;
                            self.phase = Phase::Leave { dir: dir.reverse() };
                        } else {
                            self.jog(axis, dir, p.search_velocity)?;
                            self.phase = Phase::Search { dir };
                        }
                    }
                }
            }
            Phase::Search { dir } => {
                let (flag, _) =
                    Self::zone(axis, self.method.reference).unwrap_or((Switches::NONE, None));
                if flag.any() && st.switches.contains(flag) {
                    // Decelerate, turn round and creep back: the ramp runs through zero.
                    self.jog(axis, dir.reverse(), p.crawl_velocity)?;
                    self.phase = Phase::Leave { dir: dir.reverse() };
                } else {
                    let limit_in_way = match dir {
                        Direction::Positive => Switches::LIMIT_POSITIVE,
                        Direction::Negative => Switches::LIMIT_NEGATIVE,
                    };
                    let stalled = self.stalled(&st, p.stop_time);
                    if stalled
                        || travelled > self.max_search(axis)
                        || (flag != limit_in_way && st.switches.contains(limit_in_way))
                    {
                        return Err(HomingError::NotFound {
                            searched: self.searched(),
                            travelled,
                        });
                    }
                }
            }
            Phase::Leave { dir } => {
                let (flag, zone) =
                    Self::zone(axis, self.method.reference).unwrap_or((Switches::NONE, None));
                let moving_away = st.velocity.signum() == i64::from(dir.sign());
                if st.falling.contains(flag)
                    && moving_away
                    && let Some(z) = zone
                {
                    let edge = match dir {
                        Direction::Negative => z.from,
                        Direction::Positive => z.to,
                    };
                    if self.method.index {
                        let beyond = st
                            .index_pulse
                            .map(|p| p - axis.origin())
                            .filter(|&p| (p - edge).signum() == i64::from(dir.sign()));
                        match beyond {
                            Some(p) => self.found(axis, p),
                            None => {
                                axis.arm_index_latch();
                                self.start_raw = edge;
                                self.phase = Phase::Index { dir };
                            }
                        }
                    } else {
                        self.found(axis, edge);
                    }
                } else if self.stalled(&st, p.stop_time) || travelled > self.max_search(axis) {
                    return Err(HomingError::NotFound {
                        searched: self.searched(),
                        travelled,
                    });
                }
            }
            Phase::Index { .. } => {
                if let Some(p) = axis.index_latch() {
                    let r = p - axis.origin();
                    self.found(axis, r);
                } else {
                    let n = axis.config().mechanics.encoder_increments as u64;
                    if self.stalled(&st, p.stop_time) || travelled > n.saturating_mul(2) {
                        return Err(HomingError::NotFound {
                            searched: Searched::IndexPulse,
                            travelled,
                        });
                    }
                }
            }
            Phase::StopSearch { dir, pushing_since } => {
                let pushing = st.blocked && st.current_ma.signum() as i64 == i64::from(dir.sign());
                let since = if pushing {
                    Some(pushing_since.unwrap_or(st.time))
                } else {
                    None
                };
                if since.is_some_and(|t| st.time - t >= p.stop_time) {
                    axis.stop_at_actual();
                    axis.set_current_limit(None);
                    axis.set_following_error_monitoring(true);
                    self.phase = Phase::Stopping { reference: raw };
                    return Ok(HomingState::Running);
                }
                if travelled > self.max_search(axis) {
                    return Err(HomingError::NotFound {
                        searched: self.searched(),
                        travelled,
                    });
                }
                self.phase = Phase::StopSearch {
                    dir,
                    pushing_since: since,
                };
            }
            Phase::Stopping { reference } => {
                if st.generator_done {
                    let az = reference.saturating_add(p.offset);
                    let to_az = p.travel_to_offset
                        || matches!(self.method.reference, Reference::FixedStop(_));
                    if to_az {
                        let v = p.travel_velocity;
                        let a = p.acceleration;
                        axis.move_to(
                            az.saturating_add(axis.origin()),
                            super::axis::Profile {
                                velocity: v,
                                acceleration: a,
                                deceleration: a,
                            },
                        )?;
                        self.phase = Phase::Travel { reference };
                    } else {
                        axis.set_reference(az, p.home_position);
                        return Ok(self.finish(
                            axis,
                            HomingState::Done {
                                reference_raw: reference,
                            },
                        ));
                    }
                }
            }
            Phase::Travel { reference } => {
                if st.generator_done && st.following_error == 0 {
                    axis.set_reference(reference.saturating_add(p.offset), p.home_position);
                    return Ok(self.finish(
                        axis,
                        HomingState::Done {
                            reference_raw: reference,
                        },
                    ));
                }
            }
            Phase::Finished(s) => return Ok(s),
        }
        Ok(self.state())
    }

    /// Pushing against the end of travel at the current limit for `time`: the search ran
    /// into the mechanical end.
    fn stalled(&mut self, st: &super::axis::Status, time: Duration) -> bool {
        if st.blocked {
            let since = *self.blocked_since.get_or_insert(st.time);
            st.time - since >= time
        } else {
            self.blocked_since = None;
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::axis::{Config, SwitchZone};

    const PARAMS: HomingParams = HomingParams {
        search_velocity: 20_000,
        crawl_velocity: 1_000,
        travel_velocity: 10_000,
        acceleration: 400_000,
        offset: 500,
        travel_to_offset: false,
        home_position: 7,
        stop_current_ma: 1_500,
        stop_time: Duration::from_millis(20),
        max_search: None,
    };

    /// Travel 0..100000, LIMN below 1000, LIMP from 99000, reference cam 40000..41000,
    /// index pulses at 123 + k * 2000.
    fn config() -> Config {
        let mut cfg = Config::default();
        cfg.environment.travel = Some((0, 100_000));
        cfg.environment.limit_negative = Some(SwitchZone::below(1_000));
        cfg.environment.limit_positive = Some(SwitchZone::above(99_000));
        cfg.environment.reference = Some(SwitchZone::cam(40_000, 41_000));
        cfg.environment.index_phase = 123;
        cfg
    }

    fn home(cfg: Config, method: i8, start: i64, params: HomingParams) -> (HomingState, Axis) {
        let mut axis = Axis::new(cfg, start);
        axis.enable().unwrap();
        let mut h = Homing::new(HomingMethod::from_number(method).unwrap(), params);
        assert_eq!(h.update(&mut axis), HomingState::Running);
        for _ in 0..2_000_000 {
            axis.step();
            match h.update(&mut axis) {
                HomingState::Running => {}
                s => {
                    // Let the axis settle, then the reference must still hold.
                    for _ in 0..400 {
                        axis.step();
                    }
                    return (s, axis);
                }
            }
        }
        panic!("homing {method} never ended: {:?}", axis.status());
    }

    #[test]
    fn every_method_ends_referenced_at_the_expected_position() {
        // (method, start, REF in raw increments)
        let cases: [(i8, i64, i64); 14] = [
            (17, 60_000, 1_000),
            (1, 60_000, 2_123),
            (18, 60_000, 99_000),
            (2, 60_000, 98_123),
            (23, 10_000, 40_000),
            (23, 40_500, 40_000), // starts on the switch: creeps off it negative
            (7, 10_000, 38_123),
            (27, 60_000, 41_000),
            (11, 60_000, 42_123),
            (33, 60_000, 58_123),
            (34, 60_000, 60_123),
            (35, 60_000, 60_000),
            (-17, 60_000, 0),
            (-18, 60_000, 100_000),
        ];
        for (method, start, reference) in cases {
            let mut p = PARAMS;
            if method == -18 {
                p.offset = -500;
            }
            let (state, axis) = home(config(), method, start, p);
            assert_eq!(
                state,
                HomingState::Done {
                    reference_raw: reference
                },
                "method {method}"
            );
            // AZ = REF + offset reads the home position.
            let az = reference.saturating_add(p.offset);
            assert_eq!(axis.origin(), 7 - az, "method {method}");
            let s = axis.status();
            assert!(!s.faults.any(), "method {method}: {:?}", s.faults);
            if method == -17 || method == -18 {
                // Stop methods travel to AZ.
                assert_eq!(s.position, 7, "method {method}");
                assert_eq!(axis.raw_position(), az);
            }
        }
    }

    #[test]
    fn travel_to_offset_ends_at_the_home_position() {
        let mut p = PARAMS;
        p.travel_to_offset = true;
        p.offset = 2_500;
        let (state, axis) = home(config(), 27, 60_000, p);
        assert_eq!(
            state,
            HomingState::Done {
                reference_raw: 41_000
            }
        );
        assert_eq!(axis.status().position, 7);
        assert_eq!(axis.raw_position(), 43_500);
    }

    #[test]
    fn homing_fails_cleanly_without_its_switch() {
        // 23 searches positive from above the cam: it meets LIMP first.
        let (state, axis) = home(config(), 23, 60_000, PARAMS);
        assert!(matches!(
            state,
            HomingState::Failed(HomingError::NotFound {
                searched: Searched::ReferenceSwitch,
                ..
            })
        ));
        assert_eq!(axis.origin(), 0, "no reference set");
        assert!(axis.status().standstill);

        // No switches at all: the search runs into the end of travel.
        let mut cfg = config();
        cfg.environment.reference = None;
        cfg.environment.limit_negative = None;
        let (state, _) = home(cfg, 17, 60_000, PARAMS);
        assert!(
            matches!(
                state,
                HomingState::Failed(HomingError::NotFound {
                    searched: Searched::LimitSwitch(Direction::Negative),
                    travelled: 60_000,
                })
            ),
            "{state:?}"
        );

        // An endless axis with a search distance: fails after it.
        let mut cfg = config();
        cfg.environment.travel = None;
        cfg.environment.reference = None;
        cfg.environment.limit_negative = None;
        let mut p = PARAMS;
        p.max_search = Some(30_000);
        let (state, _) = home(cfg, 27, 60_000, p);
        assert!(matches!(
            state,
            HomingState::Failed(HomingError::NotFound { travelled, .. }) if travelled > 30_000
        ));
    }

    #[test]
    fn disabling_aborts_homing_and_keeps_the_old_reference() {
        let mut axis = Axis::new(config(), 60_000);
        axis.enable().unwrap();
        axis.set_actual_position(5);
        let mut h = Homing::new(HomingMethod::from_number(27).unwrap(), PARAMS);
        h.update(&mut axis);
        for _ in 0..100 {
            axis.step();
            h.update(&mut axis);
        }
        axis.disable();
        axis.step();
        assert_eq!(
            h.update(&mut axis),
            HomingState::Failed(HomingError::Aborted {
                reason: AbortReason::Disabled
            })
        );
        assert_eq!(axis.origin(), 5 - 60_000);
    }

    #[test]
    fn method_numbers_map_to_descriptions() {
        use Direction::{Negative as N, Positive as P};
        let m = |n| HomingMethod::from_number(n).unwrap();
        assert_eq!(m(-17).reference, Reference::FixedStop(N));
        assert_eq!(m(-18).reference, Reference::FixedStop(P));
        assert_eq!(
            m(11),
            HomingMethod {
                reference: Reference::ReferenceSwitch(N),
                index: true
            }
        );
        assert_eq!(m(37).reference, Reference::CurrentPosition);
        assert_eq!(HomingMethod::from_number(3), None);
        assert_eq!(HomingMethod::from_number(0), None);
    }
}
