//! The scenario's client: keeps the machine moving (a new move for every idle group and lone
//! axis), and after faults end, recovers as an operator would (acknowledge, enable, home), all
//! through the loop's command path ([`VirtualRun::submit`]). It also keeps the books of every
//! command: each must be answered exactly once (invariant 4).

use std::collections::HashMap;
use std::time::Duration;

use drivers::time::Instant;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::invariants::Violation;
use crate::admission::{AxisActivity, GroupActivity};
use crate::command::{BufferMode, Command, Reply, Target};
use crate::ids::MAX_GROUP_AXES;
use crate::runtime::plan::MachinePlan;
use crate::runtime::virtual_clock::VirtualRun;

/// Cycles after which an unanswered command counts as lost.
pub const ANSWER_CYCLES: u64 = 20;
/// How often the operator looks at the machine.
const LOOK: Duration = Duration::from_millis(20);
/// How long after the last fault ends the operator starts recovering.
const QUIET: Duration = Duration::from_millis(100);
/// Time between two recovery commands.
const RECOVERY_STEP: Duration = Duration::from_millis(250);

/// What happened to the commands.
#[derive(Debug, Clone, Copy, Default)]
pub struct Books {
    /// Commands submitted.
    pub submitted: u64,
    /// Latched.
    pub accepted: u64,
    /// Refused by the admission table (with a reason).
    pub refused: u64,
    /// Refused at the door: the coordinator's inbox was full (the client knows at once).
    pub refused_at_door: u64,
    /// Never answered.
    pub lost: u64,
    /// Answered twice, or an answer to no command.
    pub doubled: u64,
    /// Recovery commands (acknowledge, enable, home) among them.
    pub recovery: u64,
}

/// The client.
#[derive(Debug)]
pub struct Operator {
    groups: Vec<Vec<usize>>,
    lone: Vec<usize>,
    limits: Vec<(i64, i64)>,
    rng: ChaCha8Rng,
    pending: HashMap<u64, u64>,
    /// The books.
    pub books: Books,
    next_look: Instant,
    next_recovery: Instant,
    /// The recovery step to try first next time (acknowledge, enable, home).
    turn: usize,
}

impl Operator {
    /// The client of `plan`'s machine, its moves drawn from `rng`.
    pub fn new(plan: &MachinePlan, rng: ChaCha8Rng, now: Instant) -> Operator {
        let groups: Vec<Vec<usize>> = plan
            .groups
            .iter()
            .map(|(_, g, _)| g.axes.iter().map(|&a| usize::from(a)).collect())
            .collect();
        let lone = (0..plan.axes.len())
            .filter(|a| !groups.iter().any(|g| g.contains(a)))
            .collect();
        Operator {
            groups,
            lone,
            limits: plan
                .axes
                .iter()
                .map(|a| (a.setup.position_min, a.setup.position_max))
                .collect(),
            rng,
            pending: HashMap::new(),
            books: Books::default(),
            next_look: now,
            next_recovery: now,
            turn: 0,
        }
    }

    /// Submits a command and books it.
    pub fn submit(&mut self, run: &mut VirtualRun<'_>, c: Command) {
        self.books.submitted += 1;
        match run.submit(c) {
            Some(tag) => {
                self.pending.insert(tag, run.cycles());
            }
            None => self.books.refused_at_door += 1,
        }
    }

    fn target(&mut self, a: usize) -> i64 {
        let (min, max) = self.limits[a];
        let margin = (max - min) / 20;
        if max - margin <= min + margin {
            return min;
        }
        self.rng.gen_range(min + margin..=max - margin)
    }

    /// Acts on the machine at `now`: recovery when it needs it and no fault has run for a
    /// while (`quiet_since`: when the last fault ended, `None` while one runs), else new moves.
    pub fn act(&mut self, run: &mut VirtualRun<'_>, now: Instant, quiet_since: Option<Instant>) {
        if now < self.next_look {
            return;
        }
        self.next_look = now + LOOK;
        let c = &run.stepper.cycle;
        let n = c.axis_count();
        let st: Vec<_> = (0..n).filter_map(|a| c.axis_status(a as u16)).collect();
        let needs_recovery = st.iter().any(|s| {
            !s.online
                || !s.enabled
                || !s.feedback.homed
                || matches!(
                    s.activity,
                    AxisActivity::ErrorStop | AxisActivity::QuickStopped | AxisActivity::Disabled
                )
        });
        if needs_recovery {
            let quiet = quiet_since.is_some_and(|t| now.saturating_duration_since(t) >= QUIET);
            if !quiet || now < self.next_recovery {
                return;
            }
            self.next_recovery = now + RECOVERY_STEP;
            // Acknowledge, enable, home: each when some axis needs it, in turn, so that one
            // axis that stays away (a drive that does not come back) does not hold the others.
            let ack = st.iter().any(|s| s.activity == AxisActivity::ErrorStop);
            let enable = st.iter().any(|s| {
                s.online
                    && matches!(
                        s.activity,
                        AxisActivity::Disabled | AxisActivity::QuickStopped
                    )
            });
            let unhomed: Vec<usize> = st
                .iter()
                .enumerate()
                .filter(|(_, s)| {
                    s.online
                        && s.enabled
                        && !s.feedback.homed
                        && s.activity == AxisActivity::Standstill
                })
                .map(|(a, _)| a)
                .collect();
            let needed = [ack, enable, !unhomed.is_empty()];
            let Some(step) = (0..3).map(|i| (self.turn + i) % 3).find(|&i| needed[i]) else {
                return;
            };
            self.turn = (step + 1) % 3;
            match step {
                0 => {
                    self.books.recovery += 1;
                    self.submit(run, Command::Acknowledge(Target::All));
                }
                1 => {
                    self.books.recovery += 1;
                    self.submit(run, Command::Enable(Target::All));
                }
                _ => {
                    for a in unhomed {
                        self.books.recovery += 1;
                        self.submit(run, Command::Home(Target::Axis(a as u16)));
                    }
                }
            }
            return;
        }
        // Everything is up: keep it moving.
        for g in 0..self.groups.len() {
            let idle = run
                .stepper
                .cycle
                .group_status(g as u16)
                .is_some_and(|s| s.activity == GroupActivity::Standby);
            if !idle {
                continue;
            }
            let members = self.groups[g].clone();
            let mut positions = [0i64; MAX_GROUP_AXES];
            for (i, &a) in members.iter().enumerate().take(MAX_GROUP_AXES) {
                positions[i] = self.target(a);
            }
            let velocity_percent = self.rng.gen_range(30..=100);
            self.submit(
                run,
                Command::MoveGroup {
                    group: g as u16,
                    positions,
                    velocity_percent,
                    buffer: BufferMode::Aborting,
                },
            );
        }
        for a in self.lone.clone() {
            let idle = st
                .get(a)
                .is_some_and(|s| s.activity == AxisActivity::Standstill);
            if idle {
                let position = self.target(a);
                let velocity_percent = self.rng.gen_range(30..=100);
                self.submit(
                    run,
                    Command::MoveAxis {
                        axis: a as u16,
                        position,
                        velocity_percent,
                        buffer: BufferMode::Aborting,
                    },
                );
            }
        }
    }

    /// Books the answers that came; a violation of invariant 4 if one is doubled or lost.
    pub fn collect(&mut self, run: &mut VirtualRun<'_>) -> Option<Violation> {
        let mut first = None;
        for a in run.take_answers() {
            match self.pending.remove(&a.tag) {
                Some(_) => match a.reply {
                    Reply::Latched { .. } => self.books.accepted += 1,
                    Reply::Rejected(_) => self.books.refused += 1,
                },
                None => {
                    self.books.doubled += 1;
                    first.get_or_insert(Violation {
                        invariant: 4,
                        what: format!(
                            "an answer to command {:#x}, which was answered before or never sent",
                            a.tag
                        ),
                    });
                }
            }
        }
        let k = run.cycles();
        let lost: Vec<u64> = self
            .pending
            .iter()
            .filter(|&(_, &at)| k > at + ANSWER_CYCLES)
            .map(|(&t, _)| t)
            .collect();
        for t in lost {
            self.pending.remove(&t);
            self.books.lost += 1;
            first.get_or_insert(Violation {
                invariant: 4,
                what: format!("command {t:#x} not answered within {ANSWER_CYCLES} cycles"),
            });
        }
        first
    }
}
