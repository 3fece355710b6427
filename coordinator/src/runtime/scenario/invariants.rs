//! What must hold in every cycle whatever the faults, checked after each step of a scenario:
//!
//! 1. no axis moves unless it is enabled, online and commanded (its setpoint has a velocity
//!    only in an activity that moves it);
//! 2. a fault stops the affected group: from the cycle after a member faults (the reaction runs
//!    in the detecting cycle; one cycle of slack), no member's setpoint speeds up again, no
//!    member moves in a normal activity, and the group is in its error stop, until the fault is
//!    acknowledged;
//! 3. setpoints never pass the limits: the position limits while a move streams setpoints to an
//!    enabled, homed axis, the velocity limit always;
//! 4. (commands, see `operator`) every command is answered exactly once;
//! 5. (recovery, see the runner) after the faults end and are acknowledged the machine returns
//!    to a known state.

use crate::admission::{AxisActivity, GroupActivity};
use crate::cycle::{AxisStatus, Cycle, GroupStatus};
use crate::fault::FaultReason;
use crate::runtime::plan::MachinePlan;

/// Cycles a group may take to enter its error stop after a member faults.
pub const REACTION_CYCLES: u64 = 1;

/// An invariant that did not hold.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Violation {
    /// Which invariant (1..=5).
    pub invariant: u8,
    /// What was seen, in words.
    pub what: String,
}

/// What the checks read of a cycle (the cycle itself; tests give made-up states).
pub trait Observed {
    /// An axis's status.
    fn axis(&self, a: usize) -> Option<AxisStatus>;
    /// A group's status.
    fn group(&self, g: usize) -> Option<GroupStatus>;
}

impl<const A: usize, const G: usize> Observed for Cycle<'_, A, G> {
    fn axis(&self, a: usize) -> Option<AxisStatus> {
        self.axis_status(u16::try_from(a).ok()?)
    }
    fn group(&self, g: usize) -> Option<GroupStatus> {
        self.group_status(u16::try_from(g).ok()?)
    }
}

/// Per-axis memory of the last cycle.
#[derive(Debug, Clone, Copy, Default)]
struct Last {
    velocity: i64,
    /// The cycle the current fault was first seen.
    faulted_since: Option<u64>,
}

/// The checker: the plan's limits and groups, and the last cycle's velocities and faults.
#[derive(Debug)]
pub struct Invariants {
    names: Vec<String>,
    limits: Vec<(i64, i64, u64)>,
    groups: Vec<(String, Vec<usize>)>,
    last: Vec<Last>,
}

fn moving_activity(a: AxisActivity) -> bool {
    matches!(
        a,
        AxisActivity::Homing
            | AxisActivity::Discrete
            | AxisActivity::Continuous
            | AxisActivity::Synchronized
            | AxisActivity::Stopping
            | AxisActivity::ErrorStop
    )
}

fn normal_motion(a: AxisActivity) -> bool {
    matches!(
        a,
        AxisActivity::Discrete | AxisActivity::Continuous | AxisActivity::Synchronized
    )
}

impl Invariants {
    /// The checks for `plan`.
    pub fn new(plan: &MachinePlan) -> Invariants {
        Invariants::of(
            plan.axes
                .iter()
                .map(|a| {
                    (
                        a.name.clone(),
                        (
                            a.setup.position_min,
                            a.setup.position_max,
                            a.setup.limits.velocity,
                        ),
                    )
                })
                .collect(),
            plan.groups
                .iter()
                .map(|(n, g, _)| (n.clone(), g.axes.iter().map(|&a| usize::from(a)).collect()))
                .collect(),
        )
    }

    /// The checks for axes (name, (position min, max, velocity limit), increments) and groups
    /// (name, members).
    pub fn of(
        axes: Vec<(String, (i64, i64, u64))>,
        groups: Vec<(String, Vec<usize>)>,
    ) -> Invariants {
        Invariants {
            last: vec![Last::default(); axes.len()],
            names: axes.iter().map(|(n, _)| n.clone()).collect(),
            limits: axes.iter().map(|(_, l)| *l).collect(),
            groups,
        }
    }

    /// Checks cycle `k` of `c`; the first violation found.
    pub fn check(&mut self, c: &dyn Observed, k: u64) -> Option<Violation> {
        let mut first = None;
        let mut note = |v: Violation| {
            if first.is_none() {
                first = Some(v);
            }
        };
        let status: Vec<Option<AxisStatus>> = (0..self.names.len()).map(|a| c.axis(a)).collect();
        for (a, s) in status.iter().enumerate() {
            let Some(s) = s else { continue };
            let name = &self.names[a];
            let (min, max, vmax) = self.limits[a];
            let v = s.setpoint_velocity;
            // 1. Moving only enabled, online and commanded.
            if v != 0 && !(s.enabled && s.online) {
                note(Violation {
                    invariant: 1,
                    what: format!(
                        "axis {name} moves ({v} inc/s) while {}",
                        if s.online { "not enabled" } else { "offline" }
                    ),
                });
            }
            if v != 0 && !moving_activity(s.activity) {
                note(Violation {
                    invariant: 1,
                    what: format!(
                        "axis {name} moves ({v} inc/s) with no motion commanded ({})",
                        s.activity.name()
                    ),
                });
            }
            // 3. Limits.
            if v.unsigned_abs() > vmax + vmax / 1000 + 1 {
                note(Violation {
                    invariant: 3,
                    what: format!(
                        "axis {name}: setpoint velocity {v} inc/s beyond its limit {vmax}"
                    ),
                });
            }
            // While a move streams setpoints to a referenced axis. (In an error stop the setpoint
            // follows the actual position the drive reports, whatever it is: a corrupted
            // position faults the axis in that cycle, and its setpoint then says "stay".)
            let referenced = s.moving
                && s.enabled
                && s.feedback.homed
                && s.activity != AxisActivity::Homing
                && s.activity != AxisActivity::ErrorStop;
            if referenced && !(min..=max).contains(&s.setpoint) {
                note(Violation {
                    invariant: 3,
                    what: format!(
                        "axis {name}: setpoint {} inc outside its limits {min}..={max}",
                        s.setpoint
                    ),
                });
            }
            let last = &mut self.last[a];
            if s.fault == FaultReason::None {
                last.faulted_since = None;
            } else if last.faulted_since.is_none() {
                last.faulted_since = Some(k);
            }
        }
        // 2. A fault stops the group (and a faulted axis on its own).
        for (a, s) in status.iter().enumerate() {
            let Some(s) = s else { continue };
            let since = self.last[a].faulted_since;
            if since.is_some_and(|f| k > f + REACTION_CYCLES) {
                let prev = self.last[a].velocity;
                if s.setpoint_velocity.unsigned_abs() > prev.unsigned_abs() {
                    note(Violation {
                        invariant: 2,
                        what: format!(
                            "axis {} faulted ({}) and its setpoint speeds up: {prev} -> {} inc/s",
                            self.names[a], s.fault, s.setpoint_velocity
                        ),
                    });
                }
            }
        }
        for (g, (gname, members)) in self.groups.iter().enumerate() {
            let Some(f) = members.iter().find(|&&m| {
                self.last[m]
                    .faulted_since
                    .is_some_and(|f| k > f + REACTION_CYCLES)
            }) else {
                continue;
            };
            let gs = c.group(g);
            if let Some(gs) = gs
                && gs.activity != GroupActivity::ErrorStop
            {
                note(Violation {
                    invariant: 2,
                    what: format!(
                        "group {gname}: member {} faulted ({}) but the group is {}",
                        self.names[*f],
                        status[*f].map_or_else(|| "?".to_string(), |s| s.fault.to_string()),
                        gs.activity.name()
                    ),
                });
            }
            for &m in members {
                let Some(s) = status[m] else { continue };
                let prev = self.last[m].velocity;
                if normal_motion(s.activity) && s.setpoint_velocity != 0 {
                    note(Violation {
                        invariant: 2,
                        what: format!(
                            "group {gname}: member {} faulted, yet {} moves ({})",
                            self.names[*f],
                            self.names[m],
                            s.activity.name()
                        ),
                    });
                }
                if s.setpoint_velocity.unsigned_abs() > prev.unsigned_abs() {
                    note(Violation {
                        invariant: 2,
                        what: format!(
                            "group {gname}: member {} faulted, yet {}'s setpoint speeds up: {prev} -> {} inc/s",
                            self.names[*f], self.names[m], s.setpoint_velocity
                        ),
                    });
                }
            }
        }
        for (a, s) in status.iter().enumerate() {
            if let Some(s) = s {
                self.last[a].velocity = s.setpoint_velocity;
            }
        }
        first
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::axis::Feedback;
    use crate::cycle::AxisMode;

    struct Fake {
        axes: Vec<AxisStatus>,
        groups: Vec<GroupActivity>,
    }

    impl Observed for Fake {
        fn axis(&self, a: usize) -> Option<AxisStatus> {
            self.axes.get(a).copied()
        }
        fn group(&self, g: usize) -> Option<GroupStatus> {
            Some(GroupStatus {
                chain: crate::records::ChainStatus::default(),
                motion: None,
                override_percent: 100,
                activity: *self.groups.get(g)?,
            })
        }
    }

    fn moving(v: i64) -> AxisStatus {
        AxisStatus {
            feedback: Feedback {
                homed: true,
                ..Feedback::default()
            },
            setpoint: 500,
            setpoint_velocity: v,
            fault: FaultReason::None,
            online: true,
            enabled: true,
            mode: AxisMode::On,
            moving: v != 0,
            activity: if v != 0 {
                AxisActivity::Synchronized
            } else {
                AxisActivity::Standstill
            },
        }
    }

    fn checker() -> Invariants {
        Invariants::of(
            vec![("x".into(), (0, 1000, 100)), ("y".into(), (0, 1000, 100))],
            vec![("g".into(), vec![0, 1])],
        )
    }

    fn first(fakes: &[Fake]) -> Option<Violation> {
        let mut c = checker();
        fakes
            .iter()
            .enumerate()
            .find_map(|(k, f)| c.check(f, k as u64))
    }

    #[test]
    fn normal_motion_and_a_proper_fault_stop_pass() {
        let mut f = Vec::new();
        for v in [0, 10, 20, 30] {
            f.push(Fake {
                axes: vec![moving(v), moving(v)],
                groups: vec![GroupActivity::Moving],
            });
        }
        // x faults at cycle 4; the group decelerates and holds.
        for v in [30, 20, 10, 0, 0] {
            let mut x = moving(v);
            x.fault = FaultReason::HeartbeatLost;
            x.activity = AxisActivity::ErrorStop;
            let mut y = moving(v);
            y.activity = if v == 0 {
                AxisActivity::Standstill
            } else {
                AxisActivity::Stopping
            };
            f.push(Fake {
                axes: vec![x, y],
                groups: vec![GroupActivity::ErrorStop],
            });
        }
        assert_eq!(first(&f), None);
    }

    #[test]
    fn each_broken_invariant_is_found() {
        let ok = || Fake {
            axes: vec![moving(0), moving(0)],
            groups: vec![GroupActivity::Standby],
        };
        // 1: moving while disabled, or with nothing commanded.
        let mut f = ok();
        f.axes[0].setpoint_velocity = 5;
        f.axes[0].enabled = false;
        f.axes[0].activity = AxisActivity::Synchronized;
        assert_eq!(first(&[f]).map(|v| v.invariant), Some(1));
        let mut f = ok();
        f.axes[1].setpoint_velocity = -5;
        assert_eq!(first(&[f]).map(|v| v.invariant), Some(1));
        // 3: beyond the position limits, or the velocity limit.
        let mut f = ok();
        f.axes[0] = moving(10);
        f.axes[0].setpoint = 1001;
        assert_eq!(first(&[f]).map(|v| v.invariant), Some(3));
        let mut f = ok();
        f.axes[0] = moving(102);
        assert_eq!(first(&[f]).map(|v| v.invariant), Some(3));
        // 2: after a member's fault, the group moves on or speeds up.
        let fault = |vx: i64, vy: i64, g: GroupActivity| {
            let mut x = moving(vx);
            x.fault = FaultReason::HeartbeatLost;
            x.activity = AxisActivity::ErrorStop;
            let mut y = moving(vy);
            y.activity = AxisActivity::Stopping;
            Fake {
                axes: vec![x, y],
                groups: vec![g],
            }
        };
        let v = first(&[
            fault(30, 30, GroupActivity::ErrorStop),
            fault(30, 30, GroupActivity::ErrorStop),
            fault(20, 40, GroupActivity::ErrorStop),
        ]);
        assert_eq!(v.as_ref().map(|v| v.invariant), Some(2), "{v:?}");
        assert!(v.unwrap().what.contains("y's setpoint speeds up"));
        let v = first(&[
            fault(30, 30, GroupActivity::Moving),
            fault(20, 20, GroupActivity::Moving),
            fault(10, 10, GroupActivity::Moving),
        ]);
        assert_eq!(v.as_ref().map(|v| v.invariant), Some(2), "{v:?}");
        let mut f = fault(10, 10, GroupActivity::ErrorStop);
        f.axes[1].activity = AxisActivity::Synchronized;
        let v = first(&[
            fault(10, 10, GroupActivity::ErrorStop),
            fault(10, 10, GroupActivity::ErrorStop),
            f,
        ]);
        assert_eq!(v.as_ref().map(|v| v.invariant), Some(2), "{v:?}");
    }
}
