//! The FHPP state machine (MTR-DCI §B.3, EMCA p.117–122, CMMO-ST §5.2) as a pure step function,
//! and the master-side helpers that drive it from outside.
//!
//! Main states S1..S6 with transitions T1..T11; inside S4 "Operation enabled" the sub-states
//! SA1..SA6 with TA1..TA12. T4, T6 and T7 fire from every sub-state and take priority over any
//! TA; T7 (fault) has the highest priority and also fires from S5/S6 when a fault of higher
//! priority appears.
//!
//! A simulator calls [`Machine::step`] once per drive cycle with the control bytes it received
//! and the [`Conditions`] its axis model reports; it gets the next machine and the [`Actions`]
//! to carry out (start a task, quick stop, capture a teach value, ...). One step takes at most one
//! main transition, as a drive does per cycle: CCON 0x03 from S2 reaches S4 in two steps.
//!
//! The master side uses [`bring_up`] (what to put in CCON to reach "Operation enabled" from any
//! state), [`StartHandshake`] (the START → ACK → START=0 → ACK=0 → MC sequence) and
//! [`SposEdges`].

use super::control::{Ccon, Cpos};
use super::status::{Scon, Spos};
use super::{ControlMode, Opm, Variant};

/// The main states.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum State {
    /// S1 Controller switched on (power-on; left at once by T1 when no fault is present).
    SwitchedOn,
    /// S2 Drive blocked (ENABLE = 0 or enable prerequisites missing).
    DriveBlocked,
    /// S3 Drive enabled (controller on, STOP active).
    DriveEnabled,
    /// S4 Operation enabled, with its sub-state.
    OperationEnabled(Sub),
    /// S5 Reaction to fault (the drive brakes per its fault reaction).
    FaultReaction,
    /// S6 Fault (stopped, waiting for an acknowledge).
    Fault,
}

impl State {
    /// The main state's name as the manuals write it (without "Sn"), for people.
    pub const fn name(self) -> &'static str {
        match self {
            State::SwitchedOn => "Controller switched on",
            State::DriveBlocked => "Drive blocked",
            State::DriveEnabled => "Drive enabled",
            State::OperationEnabled(_) => "Operation enabled",
            State::FaultReaction => "Reaction to fault",
            State::Fault => "Fault",
        }
    }

    /// The manual's number n of "Sn".
    pub const fn number(self) -> u8 {
        match self {
            State::SwitchedOn => 1,
            State::DriveBlocked => 2,
            State::DriveEnabled => 3,
            State::OperationEnabled(_) => 4,
            State::FaultReaction => 5,
            State::Fault => 6,
        }
    }

    /// The main state an observer infers from the status bytes (master side). Inside S4 only
    /// Ready (MC = 1), Halted (SPOS.HALT = 0, MC = 0) and Positioning (anything else running)
    /// can be told apart: homing and jog look like Positioning.
    pub const fn observe(scon: Scon, spos: Spos) -> State {
        if scon.fault {
            State::Fault
        } else if !scon.enabled {
            State::DriveBlocked
        } else if !scon.open {
            State::DriveEnabled
        } else if spos.mc {
            State::OperationEnabled(Sub::Ready)
        } else if !spos.halt {
            State::OperationEnabled(Sub::Halted)
        } else {
            State::OperationEnabled(Sub::Positioning)
        }
    }
}

/// The sub-states of S4. Names are the manuals'; the SA numbers differ between the manuals
/// (see [`Sub::number`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Sub {
    /// Ready: no task active.
    Ready,
    /// Positioning task active (position, speed and force tasks all run here).
    Positioning,
    /// Intermediate stop (halt): the position task stays active.
    Halted,
    /// Homing running.
    Homing,
    /// Jog positive.
    JogPositive,
    /// Jog negative.
    JogNegative,
}

impl Sub {
    /// The sub-state's name as the manuals write it, for people.
    pub const fn name(self) -> &'static str {
        match self {
            Sub::Ready => "Ready",
            Sub::Positioning => "Positioning",
            Sub::Halted => "Intermediate stop",
            Sub::Homing => "Homing",
            Sub::JogPositive => "Jog positive",
            Sub::JogNegative => "Jog negative",
        }
    }

    /// The SA number the variant's manual gives: MTR-DCI and EMCA number homing SA4, jog + SA5,
    /// jog − SA6; the CMMO-ST manual numbers jog + SA4, jog − SA5, homing SA6. The TA numbers
    /// are the same in all three (TA7 starts homing, TA9 jog +, TA11 jog −).
    pub const fn number(self, variant: Variant) -> u8 {
        let cmmo = matches!(variant, Variant::CmmoSt);
        match self {
            Sub::Ready => 1,
            Sub::Positioning => 2,
            Sub::Halted => 3,
            Sub::Homing => {
                if cmmo {
                    6
                } else {
                    4
                }
            }
            Sub::JogPositive => {
                if cmmo {
                    4
                } else {
                    5
                }
            }
            Sub::JogNegative => {
                if cmmo {
                    5
                } else {
                    6
                }
            }
        }
    }
}

/// The transitions, numbered as in the manuals' tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[allow(missing_docs)] // each variant is its manual number; the table is in `Machine::step`
pub enum Transition {
    T1,
    T2,
    T3,
    T4,
    T5,
    T6,
    T7,
    T8,
    T9,
    T10,
    T11,
    TA1,
    TA2,
    TA3,
    TA4,
    TA5,
    TA6,
    TA7,
    TA8,
    TA9,
    TA10,
    TA11,
    TA12,
}

/// How a fault is acknowledged (T9 vs T10). The manuals leave the classification to the
/// device: MTR-DCI digest E9 proposes serious = 51, 52, 70, 100, 101 and simple = 1, 2, 31, 32,
/// 106; EMCA/CMMO-ST classify by the fault reaction (A–D output stage off = serious, E–G on =
/// simple).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FaultClass {
    /// T9: back to S2 "Drive blocked"; the output stage was switched off.
    Serious,
    /// T10: back to S3 "Drive enabled" (with ENABLE = 1); the output stage stayed on.
    Simple,
}

/// What a START edge does while a task runs (TA5 b): EMCA/CMMO-ST PNU 583 (direct) or RCB3 =
/// PNU 421 (records). The MTR-DCI has no such parameter: in direct mode its simulator retargets
/// (digest 000 E7, `Interrupt`), in record select it ignores the edge (enforced by the step).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum StartCondition {
    /// 0: ignore the START (the CMMO-ST's PNU 583 default).
    #[default]
    Ignore,
    /// 1: switch to the new task at once.
    Interrupt,
    /// 2: start the new task after MC of the running one.
    Wait,
}

impl StartCondition {
    /// From the parameter value (bits 1..0); 3 (reserved) is treated as `Ignore`.
    pub const fn from_bits(v: u8) -> StartCondition {
        match v & 0b11 {
            1 => StartCondition::Interrupt,
            2 => StartCondition::Wait,
            _ => StartCondition::Ignore,
        }
    }
}

/// What the axis model reports to the state machine each cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Conditions {
    /// A fault was recognised this cycle (or one of higher priority than the latched one): T7.
    pub new_fault: Option<FaultClass>,
    /// The latched fault's cause is still present: an acknowledge is refused (T11).
    pub fault_cause_present: bool,
    /// The fault reaction has finished and the drive stands still: T8.
    pub reaction_done: bool,
    /// Load voltage applied (SCON.24VL / VLOAD); needed for T2.
    pub load_voltage: bool,
    /// The fieldbus holds device control (PNU 125 = 1, FCT/HMI not in control). Without it the
    /// control bytes are ignored, STOP included (MTR-DCI §4.6).
    pub fieldbus_control: bool,
    /// Other enable prerequisites: STO and the enable input (EMCA/CMMO-ST PNU 280, PNU 128).
    pub enable_permitted: bool,
    /// The axis is referenced (SPOS.REF); TA1 requires it.
    pub referenced: bool,
    /// The task started by the latest command is complete: target window held for the settling
    /// time, homing finished, or (when no task runs) the axis stands still after a stop/jog.
    pub motion_complete: bool,
    /// The task a START would take over is executable (record number valid, record initialised
    /// with v ≠ 0, target inside the software limits, mode supported). The simulator checks.
    pub task_valid: bool,
    /// Record select: the finished record chains to the next one by itself (TA5 a).
    pub chain_continues: bool,
    /// What a START edge does while a task runs (TA5 b).
    pub start_condition: StartCondition,
    /// The control mode of the running task: HALT keeps a position task (SA3) but ends a speed or
    /// force task.
    pub task_mode: ControlMode,
}

impl Conditions {
    /// A healthy, idle, unreferenced axis under fieldbus control with load voltage.
    pub const fn healthy() -> Conditions {
        Conditions {
            new_fault: None,
            fault_cause_present: false,
            reaction_done: true,
            load_voltage: true,
            fieldbus_control: true,
            enable_permitted: true,
            referenced: false,
            motion_complete: true,
            task_valid: true,
            chain_continues: false,
            start_condition: StartCondition::Ignore,
            task_mode: ControlMode::Position,
        }
    }
}

/// The jog direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Toward larger actual values (JOGP).
    Positive,
    /// Toward smaller actual values (JOGN).
    Negative,
}

/// What the drive must do as a result of a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// T2: switch the controller on.
    Enable,
    /// T5/T6: block the drive (a running task stops with the quick-stop ramp, then the output
    /// stage goes off).
    Disable,
    /// T4: STOP = 0: quick-stop (MTR-DCI: emergency) ramp, the task is cancelled.
    QuickStop,
    /// T7: run the fault reaction.
    FaultReaction,
    /// TA1, TA5 (interrupt): take over the record/direct setpoints and start.
    StartTask,
    /// TA5 (wait): take over the setpoints and start them after MC of the running task.
    QueueTask,
    /// TA5 (chaining): the drive continues with the next record by itself.
    NextRecord,
    /// TA3 (position: task kept) or TA2 (speed/force: task ended), TA8 (homing aborted):
    /// brake on the task (halt) ramp.
    Halt,
    /// TA4: resume the halted task.
    Resume,
    /// TA6: delete the remaining path.
    Clear,
    /// TA7: start homing.
    StartHoming,
    /// TA9/TA11: start jogging.
    StartJog(Direction),
    /// TA10/TA12: stop jogging (brake with the jog/maximum deceleration).
    StopJog,
}

/// Why a START or HOM edge was not taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Refusal {
    /// START without a valid reference (MTR-DCI fault 1, EMCA/CMMO-ST diagnosis 28h).
    NotReferenced,
    /// The task is not executable ([`Conditions::task_valid`] was false). The simulator knows
    /// which device reaction applies (MTR-DCI warning 3 / fault 2; CMMO-ST 3Fh / 29h / 2Ah).
    InvalidTask,
    /// START and HOM rose in the same cycle (CMMO-ST diagnosis 3Ch "two edges in one cycle";
    /// other variants give homing the priority instead).
    SimultaneousStarts,
}

/// The outcome of one step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Actions {
    /// The transition taken, if any.
    pub transition: Option<Transition>,
    /// The command for the motion/drive model.
    pub command: Option<Command>,
    /// A TEACH falling edge in S4: store the actual position into the PNU 520 target.
    pub teach_capture: bool,
    /// Faults (T9/T10) or warnings (RESET edge outside S6) are to be cleared.
    pub acknowledge: bool,
    /// A START/HOM edge that was not taken.
    pub refusal: Option<Refusal>,
}

/// The control bytes the state machine reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Control {
    /// CCON.
    pub ccon: Ccon,
    /// CPOS.
    pub cpos: Cpos,
}

impl Control {
    /// From the two bytes.
    pub const fn from_bytes(ccon: u8, cpos: u8) -> Control {
        Control {
            ccon: Ccon::from_byte(ccon),
            cpos: Cpos::from_byte(cpos),
        }
    }
}

/// The FHPP state machine of one drive, with the handshake bits it owns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Machine {
    /// The current state.
    pub state: State,
    /// The operating mode in force (SCON.OPM); CCON.OPM is taken over only in S2, S3 and SA1.
    pub opm: Opm,
    /// SPOS.ACK.
    pub ack: bool,
    /// SPOS.MC (1 at power-on).
    pub mc: bool,
    /// SPOS.TEACH.
    pub teach: bool,
    /// The class of the latched fault (meaningful in S5/S6).
    pub fault_class: FaultClass,
    /// The control bytes of the previous step, for edge detection.
    pub last: Control,
}

impl Default for Machine {
    fn default() -> Machine {
        Machine::power_on()
    }
}

/// Rising/falling edges between two control images.
#[derive(Debug, Clone, Copy)]
struct Edges {
    reset_rise: bool,
    enable_fall: bool,
    start_rise: bool,
    hom_rise: bool,
    jogp_rise: bool,
    jogn_rise: bool,
    teach_rise: bool,
    teach_fall: bool,
    clear_rise: bool,
}

impl Edges {
    fn between(a: Control, b: Control) -> Edges {
        Edges {
            reset_rise: !a.ccon.reset && b.ccon.reset,
            enable_fall: a.ccon.enable && !b.ccon.enable,
            start_rise: !a.cpos.start && b.cpos.start,
            hom_rise: !a.cpos.hom && b.cpos.hom,
            jogp_rise: !a.cpos.jogp && b.cpos.jogp,
            jogn_rise: !a.cpos.jogn && b.cpos.jogn,
            teach_rise: !a.cpos.teach && b.cpos.teach,
            teach_fall: a.cpos.teach && !b.cpos.teach,
            clear_rise: !a.cpos.clear && b.cpos.clear,
        }
    }
}

impl Machine {
    /// The machine at power-on: S1, MC = 1, record select, all control bits seen as 0.
    pub const fn power_on() -> Machine {
        Machine {
            state: State::SwitchedOn,
            opm: Opm::RecordSelect,
            ack: false,
            mc: true,
            teach: false,
            fault_class: FaultClass::Serious,
            last: Control {
                ccon: Ccon {
                    enable: false,
                    stop: false,
                    brake: false,
                    reset: false,
                    lock: false,
                    opm: Opm::RecordSelect,
                },
                cpos: Cpos {
                    halt: false,
                    start: false,
                    hom: false,
                    jogp: false,
                    jogn: false,
                    teach: false,
                    clear: false,
                },
            },
        }
    }

    /// One drive cycle: the control bytes received and the axis conditions in, the next machine
    /// and what to do out. Pure: the same inputs give the same outputs.
    pub fn step(self, variant: Variant, control: Control, cond: &Conditions) -> (Machine, Actions) {
        let mut m = self;
        let mut a = Actions::default();
        let e = Edges::between(m.last, control);
        // Edges seen while FCT/HMI holds control are dropped, not replayed later.
        m.last = control;
        let bus = cond.fieldbus_control;
        let ccon = control.ccon;
        let cpos = control.cpos;

        // T7*: highest priority, from every state (S5/S6 included: a fault of higher priority).
        if let Some(class) = cond.new_fault {
            m.fault_class = class;
            m.mc = false;
            m.go(
                &mut a,
                Transition::T7,
                State::FaultReaction,
                Some(Command::FaultReaction),
            );
            m.finish(variant, control, cond, &e, bus, &mut a);
            return (m, a);
        }

        match m.state {
            // T1: automatic.
            State::SwitchedOn => m.go(&mut a, Transition::T1, State::DriveBlocked, None),
            // T8: reaction completed, drive stopped.
            State::FaultReaction => {
                if cond.reaction_done {
                    m.go(&mut a, Transition::T8, State::Fault, None);
                }
            }
            // T9/T10/T11: acknowledge with a RESET rising edge (MTR-DCI also: ENABLE falling).
            State::Fault if bus => {
                let mtr = matches!(variant, Variant::MtrDci);
                let ack_edge = e.reset_rise || (mtr && e.enable_fall);
                if ack_edge {
                    if cond.fault_cause_present {
                        m.go(&mut a, Transition::T11, State::Fault, None);
                    } else {
                        // MTR-DCI T9 `xxx0.Pxxx`: a serious fault goes to S2 whatever ENABLE is;
                        // EMCA/CMMO-ST T9 `xxx0.Pxx0` needs ENABLE = 0, and a serious fault with
                        // ENABLE = 1 is not acknowledged. T10 `xxx0.Pxx1` for simple faults.
                        let to = match (m.fault_class, ccon.enable) {
                            (FaultClass::Simple, true) => {
                                Some((Transition::T10, State::DriveEnabled))
                            }
                            (_, false) => Some((Transition::T9, State::DriveBlocked)),
                            (FaultClass::Serious, true) if mtr => {
                                Some((Transition::T9, State::DriveBlocked))
                            }
                            (FaultClass::Serious, true) => None,
                        };
                        if let Some((t, s)) = to {
                            m.go(&mut a, t, s, None);
                            a.acknowledge = true;
                            m.mc = true;
                        }
                    }
                }
            }
            State::Fault => {}
            // T2: ENABLE = 1 with load voltage, device control and the enable prerequisites.
            State::DriveBlocked => {
                if bus && ccon.enable && cond.load_voltage && cond.enable_permitted {
                    m.go(
                        &mut a,
                        Transition::T2,
                        State::DriveEnabled,
                        Some(Command::Enable),
                    );
                }
            }
            // T5: ENABLE = 0; T3: STOP = 1 `xxx0.xx11`.
            State::DriveEnabled if bus => {
                if !ccon.enable || !cond.enable_permitted {
                    m.go(
                        &mut a,
                        Transition::T5,
                        State::DriveBlocked,
                        Some(Command::Disable),
                    );
                } else if ccon.stop {
                    m.go(
                        &mut a,
                        Transition::T3,
                        State::OperationEnabled(Sub::Ready),
                        None,
                    );
                }
            }
            State::DriveEnabled => {}
            // T6 (ENABLE = 0) and T4 (STOP = 0) from every SAx, before any TA.
            State::OperationEnabled(_) if bus && (!ccon.enable || !cond.enable_permitted) => {
                m.go(
                    &mut a,
                    Transition::T6,
                    State::DriveBlocked,
                    Some(Command::Disable),
                );
            }
            State::OperationEnabled(_) if bus && !ccon.stop => {
                m.go(
                    &mut a,
                    Transition::T4,
                    State::DriveEnabled,
                    Some(Command::QuickStop),
                );
            }
            State::OperationEnabled(sub) if bus => m.sub_step(variant, sub, cpos, cond, &e, &mut a),
            State::OperationEnabled(sub) => {
                // FCT/HMI holds control: tasks still finish.
                if cond.motion_complete && matches!(sub, Sub::Positioning | Sub::Homing) {
                    m.state = State::OperationEnabled(Sub::Ready);
                    m.mc = true;
                }
            }
        }
        m.finish(variant, control, cond, &e, bus, &mut a);
        (m, a)
    }

    /// The S4 sub-machine, TA1..TA12 (all with CCON `xxx0.xx11`).
    fn sub_step(
        &mut self,
        variant: Variant,
        sub: Sub,
        cpos: Cpos,
        cond: &Conditions,
        e: &Edges,
        a: &mut Actions,
    ) {
        let op = State::OperationEnabled;
        match sub {
            Sub::Ready => {
                let no_jog = !cpos.jogp && !cpos.jogn;
                if e.jogp_rise && !cpos.jogn && cpos.halt {
                    // TA9 `0xx0.Pxx1`: jog beats homing and START.
                    self.start(
                        a,
                        Transition::TA9,
                        Sub::JogPositive,
                        Command::StartJog(Direction::Positive),
                    );
                } else if e.jogn_rise && !cpos.jogp && cpos.halt {
                    // TA11 `0xxP.xxx1`.
                    self.start(
                        a,
                        Transition::TA11,
                        Sub::JogNegative,
                        Command::StartJog(Direction::Negative),
                    );
                } else if e.hom_rise && cpos.halt && no_jog {
                    // TA7 `0xx0.0Px1`.
                    if e.start_rise && matches!(variant, Variant::CmmoSt) {
                        a.refusal = Some(Refusal::SimultaneousStarts);
                    } else {
                        self.start(a, Transition::TA7, Sub::Homing, Command::StartHoming);
                    }
                } else if e.start_rise && cpos.halt && no_jog && !cpos.hom && !cpos.clear {
                    // TA1 `0xx0.00P1`, the drive referenced.
                    if !cond.referenced {
                        a.refusal = Some(Refusal::NotReferenced);
                    } else if !cond.task_valid {
                        a.refusal = Some(Refusal::InvalidTask);
                    } else {
                        self.start(a, Transition::TA1, Sub::Positioning, Command::StartTask);
                    }
                }
            }
            Sub::Positioning => {
                if cond.motion_complete {
                    if self.opm == Opm::RecordSelect && cond.chain_continues {
                        // TA5 (a): the next record runs without a START.
                        self.go(
                            a,
                            Transition::TA5,
                            op(Sub::Positioning),
                            Some(Command::NextRecord),
                        );
                    } else {
                        // TA2: MC = 1, no automatic next record.
                        self.go(a, Transition::TA2, op(Sub::Ready), None);
                        self.mc = true;
                    }
                } else if !cpos.halt {
                    if cond.task_mode == ControlMode::Position {
                        // TA3 `0xxx.xxxN`, MC = 0: the task is kept.
                        self.go(a, Transition::TA3, op(Sub::Halted), Some(Command::Halt));
                    } else {
                        // Speed/force: halt ends the task (EMCA/CMMO-ST); MC once stopped.
                        self.go(a, Transition::TA2, op(Sub::Ready), Some(Command::Halt));
                    }
                } else if e.start_rise {
                    // TA5 (b): a new task while one runs. The MTR-DCI's record select has no
                    // such transition (§4.3), so its START is ignored there.
                    let condition = match (variant, self.opm) {
                        (Variant::MtrDci, Opm::RecordSelect) => StartCondition::Ignore,
                        _ => cond.start_condition,
                    };
                    let command = match condition {
                        StartCondition::Ignore => None,
                        StartCondition::Interrupt => Some(Command::StartTask),
                        StartCondition::Wait => Some(Command::QueueTask),
                    };
                    if let Some(c) = command {
                        if cond.task_valid {
                            self.go(a, Transition::TA5, op(Sub::Positioning), Some(c));
                            self.ack = true;
                        } else {
                            a.refusal = Some(Refusal::InvalidTask);
                        }
                    }
                }
            }
            Sub::Halted => {
                if e.clear_rise {
                    // TA6 `0Pxx.xxxx`: delete the remaining path.
                    self.go(a, Transition::TA6, op(Sub::Ready), Some(Command::Clear));
                } else if cpos.halt && e.start_rise && !cpos.clear {
                    // TA4 `00xx.xxP1`: resume the same task.
                    self.start(a, Transition::TA4, Sub::Positioning, Command::Resume);
                }
            }
            Sub::Homing => {
                if !cpos.halt {
                    // TA8 by halt: homing aborted.
                    self.go(a, Transition::TA8, op(Sub::Ready), Some(Command::Halt));
                } else if cond.motion_complete {
                    // TA8: homing finished.
                    self.go(a, Transition::TA8, op(Sub::Ready), None);
                    self.mc = true;
                }
            }
            Sub::JogPositive => {
                // TA10: JOGP 1→0 or HALT 1→0.
                if !cpos.jogp || !cpos.halt {
                    self.go(a, Transition::TA10, op(Sub::Ready), Some(Command::StopJog));
                }
            }
            Sub::JogNegative => {
                // TA12: JOGN 1→0 or HALT 1→0.
                if !cpos.jogn || !cpos.halt {
                    self.go(a, Transition::TA12, op(Sub::Ready), Some(Command::StopJog));
                }
            }
        }
    }

    /// Takes a transition.
    fn go(&mut self, a: &mut Actions, t: Transition, to: State, command: Option<Command>) {
        self.state = to;
        a.transition = Some(t);
        a.command = command;
    }

    /// Takes a transition that starts a task: ACK = 1, MC = 0.
    fn start(&mut self, a: &mut Actions, t: Transition, to: Sub, command: Command) {
        self.go(a, t, State::OperationEnabled(to), Some(command));
        self.ack = true;
        self.mc = false;
    }

    /// The bookkeeping every step ends with: OPM take-over, teach, warning acknowledge, ACK and
    /// MC.
    fn finish(
        &mut self,
        variant: Variant,
        control: Control,
        cond: &Conditions,
        e: &Edges,
        bus: bool,
        a: &mut Actions,
    ) {
        let idle = matches!(
            self.state,
            State::SwitchedOn
                | State::DriveBlocked
                | State::DriveEnabled
                | State::OperationEnabled(Sub::Ready)
        );
        // OPM changes only in S2, S3 and SA1 (MTR-DCI §5.5.1); reserved values are not taken.
        if bus && idle && matches!(control.ccon.opm, Opm::RecordSelect | Opm::Direct) {
            self.opm = control.ccon.opm;
        }
        if bus && matches!(self.state, State::OperationEnabled(_)) {
            // MTR-DCI: SPOS.TEACH = 1 "value transferred" after the falling edge, 0 again when
            // TEACH rises. EMCA/CMMO-ST: SPOS.TEACH follows CPOS.TEACH high and its fall means
            // "stored" (CMMO-ST digest decision, EMCA p.172).
            let mtr = matches!(variant, Variant::MtrDci);
            if e.teach_rise {
                self.teach = !mtr;
            }
            if e.teach_fall {
                a.teach_capture = true;
                self.teach = mtr;
            }
        }
        if bus && e.reset_rise && !matches!(self.state, State::Fault | State::FaultReaction) {
            a.acknowledge = true;
        }
        // ACK falls once the bit that started the task is released (the 4-step handshake).
        let cpos = control.cpos;
        if self.ack && !(cpos.start || cpos.hom || cpos.jogp || cpos.jogn) {
            self.ack = false;
        }
        // No task active and the axis at rest: MC = 1 (after a stop, jog end, clear, disable).
        if idle && cond.motion_complete {
            self.mc = true;
        }
    }

    /// SCON as this machine presents it; the other bits come from the device.
    pub const fn scon(&self, variant: Variant, warn: bool, vload: bool, fct_mmi: bool) -> Scon {
        let stage_on_in_fault = matches!(self.fault_class, FaultClass::Simple);
        let (enabled, open, fault) = match self.state {
            State::SwitchedOn | State::DriveBlocked => (false, false, false),
            State::DriveEnabled => (true, false, false),
            State::OperationEnabled(_) => (true, true, false),
            // The CMMO-ST raises FAULT only at S6 ("0 = no fault or fault reaction active").
            State::FaultReaction => (
                stage_on_in_fault,
                false,
                !matches!(variant, Variant::CmmoSt),
            ),
            State::Fault => (stage_on_in_fault, false, true),
        };
        Scon {
            enabled,
            open,
            warn,
            fault,
            vload,
            fct_mmi,
            opm: self.opm,
        }
    }

    /// SPOS as this machine presents it (HALT mirrors CPOS.HALT); the motion bits come from the
    /// axis model.
    pub const fn spos(&self, mov: bool, dev: bool, still: bool, referenced: bool) -> Spos {
        Spos {
            halt: self.last.cpos.halt,
            ack: self.ack,
            mc: self.mc,
            teach: self.teach,
            mov,
            dev,
            still,
            referenced,
        }
    }
}

/// Whether FCT/HMI may take device control from the fieldbus: not while CCON.LOCK = 1.
pub const fn fct_takeover_allowed(ccon: Ccon) -> bool {
    !ccon.lock
}

/// What keeps [`bring_up`] from progressing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BringUpBlock {
    /// SCON.FCT/MMI = 1: FCT or the panel holds control (write PNU 125 = 1 after it lets go).
    FctHasControl,
    /// SCON.24VL / VLOAD = 0.
    NoLoadVoltage,
}

/// The next step of [`bring_up`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BringUp {
    /// Operation enabled in the wanted mode; keep sending this CCON.
    Ready(Ccon),
    /// Send this CCON (with [`Cpos::idle`]) and look again next cycle.
    Send(Ccon),
    /// Cannot progress from the bus.
    Blocked(BringUpBlock),
}

/// Master side: the CCON that moves a drive from any state toward S4 "Operation enabled" in
/// `opm`, given its SCON and the CCON sent last cycle. LOCK is always set. A fault is
/// acknowledged the way every variant accepts (ENABLE = 0 with a RESET rising edge, T9; the
/// RESET bit alternates so each pair of cycles makes an edge); then ENABLE and STOP together
/// (T2, T3).
pub const fn bring_up(scon: Scon, last: Ccon, opm: Opm) -> BringUp {
    let mut c = Ccon {
        enable: true,
        stop: true,
        brake: false,
        reset: false,
        lock: true,
        opm,
    };
    if scon.fct_mmi {
        return BringUp::Blocked(BringUpBlock::FctHasControl);
    }
    if scon.fault {
        c.enable = false;
        c.stop = false;
        c.reset = !last.reset;
        return BringUp::Send(c);
    }
    if !scon.vload {
        return BringUp::Blocked(BringUpBlock::NoLoadVoltage);
    }
    if scon.enabled && scon.open && scon.opm.bits() == opm.bits() {
        BringUp::Ready(c)
    } else {
        BringUp::Send(c)
    }
}

/// Edges of the SPOS handshake bits between two status images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SposEdges {
    /// ACK 0→1: the drive took the START/HOM/jog.
    pub ack_rise: bool,
    /// ACK 1→0: the drive saw START drop; the next task may be prepared.
    pub ack_fall: bool,
    /// MC 0→1.
    pub mc_rise: bool,
    /// MC 1→0: a task started.
    pub mc_fall: bool,
    /// REF 0→1: homing succeeded.
    pub ref_rise: bool,
    /// TEACH 0→1.
    pub teach_rise: bool,
    /// TEACH 1→0.
    pub teach_fall: bool,
}

impl SposEdges {
    /// The edges from `prev` to `now`.
    pub const fn between(prev: Spos, now: Spos) -> SposEdges {
        SposEdges {
            ack_rise: !prev.ack && now.ack,
            ack_fall: prev.ack && !now.ack,
            mc_rise: !prev.mc && now.mc,
            mc_fall: prev.mc && !now.mc,
            ref_rise: !prev.referenced && now.referenced,
            teach_rise: !prev.teach && now.teach,
            teach_fall: prev.teach && !now.teach,
        }
    }
}

/// Where a [`StartHandshake`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HandshakePhase {
    /// Nothing requested.
    Idle,
    /// Requested; waiting for ACK = 0 before raising START (a previous task's ACK).
    WaitReady,
    /// START = 1; waiting for ACK = 1.
    Raised,
    /// ACK = 1 seen; START = 0; waiting for ACK = 0 (and MC).
    Acknowledged,
    /// ACK = 0 again; waiting for MC = 1.
    Running,
    /// MC = 1 after the ACK: the task is complete.
    Complete,
    /// SCON.FAULT rose while the handshake ran.
    Failed,
    /// The phase took more cycles than allowed.
    TimedOut,
}

/// Master side: one START (or HOM) handshake, FHPP's 4 steps (MTR-DCI Fig. 5/4, EMCA p.180,
/// CMMO-ST Fig. 6.3): wait ACK = 0 → START = 1 → ACK = 1 → START = 0 → ACK = 0 → MC = 1.
/// MC = 1 counts only once ACK = 1 was seen, so a stale MC of the previous task is never taken
/// for completion. Fed once per cycle with the status bytes; time is counted in cycles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct StartHandshake {
    phase: HandshakePhase,
    cycles: u32,
    timeout_cycles: u32,
}

impl StartHandshake {
    /// An idle handshake whose phases each time out after `timeout_cycles` polls (0 = never).
    pub const fn new(timeout_cycles: u32) -> StartHandshake {
        StartHandshake {
            phase: HandshakePhase::Idle,
            cycles: 0,
            timeout_cycles,
        }
    }
    /// Starts a new handshake (the record number or setpoints must already be in the image).
    pub fn request(&mut self) {
        self.phase = HandshakePhase::WaitReady;
        self.cycles = 0;
    }
    /// The phase.
    pub const fn phase(&self) -> HandshakePhase {
        self.phase
    }
    /// The START (or HOM) bit to send this cycle.
    pub const fn start_bit(&self) -> bool {
        matches!(self.phase, HandshakePhase::Raised)
    }
    /// Feeds this cycle's status; returns the (possibly new) phase.
    pub fn poll(&mut self, scon: Scon, spos: Spos) -> HandshakePhase {
        use HandshakePhase as P;
        let before = self.phase;
        if matches!(before, P::Idle | P::Complete | P::Failed | P::TimedOut) {
            return before;
        }
        if scon.fault {
            self.phase = P::Failed;
            return self.phase;
        }
        self.phase = match before {
            P::WaitReady if !spos.ack => P::Raised,
            P::Raised if spos.ack && spos.mc => P::Complete,
            P::Raised if spos.ack => P::Acknowledged,
            P::Acknowledged | P::Running if spos.mc => P::Complete,
            P::Acknowledged if !spos.ack => P::Running,
            p => p,
        };
        if self.phase == before {
            self.cycles = self.cycles.saturating_add(1);
            if self.timeout_cycles != 0 && self.cycles >= self.timeout_cycles {
                self.phase = P::TimedOut;
            }
        } else {
            self.cycles = 0;
        }
        self.phase
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const MTR: Variant = Variant::MtrDci;

    fn ctl(ccon: u8, cpos: u8) -> Control {
        Control::from_bytes(ccon, cpos)
    }

    /// Steps until the state stops changing (at most 8 times), returning the last actions.
    fn settle(m: &mut Machine, v: Variant, c: Control, cond: &Conditions) -> Actions {
        let mut last = Actions::default();
        for _ in 0..8 {
            let (n, a) = m.step(v, c, cond);
            let changed = n.state != m.state;
            *m = n;
            if a != Actions::default() {
                last = a;
            }
            if !changed {
                break;
            }
        }
        last
    }

    fn enabled(v: Variant, ccon: u8) -> Machine {
        let mut m = Machine::power_on();
        settle(&mut m, v, ctl(ccon, 0x01), &Conditions::healthy());
        assert_eq!(m.state, State::OperationEnabled(Sub::Ready));
        m
    }

    fn status(m: &Machine, v: Variant, referenced: bool, mov: bool) -> (u8, u8) {
        (
            m.scon(v, false, true, false).to_byte(),
            m.spos(mov, false, false, referenced).to_byte(),
        )
    }

    #[test]
    fn power_on_image_is_scon_0x10_spos_0x04() {
        // CMMO-ST §2.4 / EMCA §2.4: SCON 0x10 (VLOAD), SPOS 0x04 (MC).
        let mut m = Machine::power_on();
        let (n, a) = m.step(Variant::CmmoSt, ctl(0x00, 0x00), &Conditions::healthy());
        assert_eq!(a.transition, Some(Transition::T1));
        m = n;
        assert_eq!(m.state, State::DriveBlocked);
        assert_eq!(status(&m, Variant::CmmoSt, false, false), (0x10, 0x04));
    }

    #[test]
    fn enabling_follows_t2_t3_and_the_reference_patterns() {
        // CMMO-ST 1.3: CCON 0x23 CPOS 0x01 → SCON 0x13 SPOS 0x05; 2.3 direct: 0x63 → 0x53.
        let cond = Conditions::healthy();
        let mut m = Machine::power_on();
        let c = ctl(0x23, 0x01);
        let (n, _) = m.step(Variant::CmmoSt, c, &cond);
        m = n;
        let (n, a) = m.step(Variant::CmmoSt, c, &cond);
        assert_eq!(a.transition, Some(Transition::T2));
        assert_eq!(a.command, Some(Command::Enable));
        assert_eq!(n.state, State::DriveEnabled);
        assert_eq!(status(&n, Variant::CmmoSt, false, false).0, 0x11);
        let (n, a) = n.step(Variant::CmmoSt, c, &cond);
        assert_eq!(a.transition, Some(Transition::T3));
        assert_eq!(status(&n, Variant::CmmoSt, false, false), (0x13, 0x05));

        let m = enabled(Variant::CmmoSt, 0x63);
        assert_eq!(status(&m, Variant::CmmoSt, false, false), (0x53, 0x05));
    }

    #[test]
    fn no_load_voltage_or_no_bus_control_blocks_t2() {
        let mut m = Machine::power_on();
        let cond = Conditions {
            load_voltage: false,
            ..Conditions::healthy()
        };
        settle(&mut m, MTR, ctl(0x03, 0x01), &cond);
        assert_eq!(m.state, State::DriveBlocked);
        let cond = Conditions {
            fieldbus_control: false,
            ..Conditions::healthy()
        };
        settle(&mut m, MTR, ctl(0x00, 0x00), &cond);
        assert_eq!(m.state, State::DriveBlocked);
        // HMI/FCT control (Tab. 5/7): SCON 0x30, SPOS 0x04.
        assert_eq!(m.scon(MTR, false, true, true).to_byte(), 0x30);
        assert_eq!(m.spos(false, false, false, false).to_byte(), 0x04);
    }

    #[test]
    fn fct_control_means_stop_cannot_stop_the_drive() {
        let mut m = enabled(MTR, 0x03);
        let cond = Conditions {
            fieldbus_control: false,
            ..Conditions::healthy()
        };
        let (n, a) = m.step(MTR, ctl(0x00, 0x00), &cond);
        assert_eq!(n.state, State::OperationEnabled(Sub::Ready));
        assert_eq!(a.transition, None);
        m = n;
        // Back under bus control, the same bytes now act (T6: ENABLE = 0).
        let (n, a) = m.step(MTR, ctl(0x00, 0x00), &Conditions::healthy());
        assert_eq!(a.transition, Some(Transition::T6));
        assert_eq!(n.state, State::DriveBlocked);
        assert!(fct_takeover_allowed(Ccon::from_byte(0x03)));
        assert!(!fct_takeover_allowed(Ccon::from_byte(0x23)));
    }

    #[test]
    fn mtr_dci_homing_sequence_tab_5_11() {
        let mut m = enabled(MTR, 0x03);
        let mut cond = Conditions::healthy();
        // Before: SPOS 0x05.
        assert_eq!(status(&m, MTR, false, false), (0x13, 0x05));
        // HOM rising edge: CPOS 0x05.
        let (n, a) = m.step(MTR, ctl(0x03, 0x05), &cond);
        assert_eq!(a.transition, Some(Transition::TA7));
        assert_eq!(a.command, Some(Command::StartHoming));
        m = n;
        cond.motion_complete = false;
        let (n, _) = m.step(MTR, ctl(0x03, 0x05), &cond);
        m = n;
        // While running: ACK = 1, MC = 0 → 0x03.
        assert_eq!(status(&m, MTR, false, false).1, 0x03);
        // HOM released: ACK falls.
        let (n, _) = m.step(MTR, ctl(0x03, 0x01), &cond);
        m = n;
        assert_eq!(status(&m, MTR, false, true).1, 0x11);
        // Homing done: TA8, SPOS 0x85.
        cond.motion_complete = true;
        cond.referenced = true;
        let (n, a) = m.step(MTR, ctl(0x03, 0x01), &cond);
        assert_eq!(a.transition, Some(Transition::TA8));
        assert_eq!(n.state, State::OperationEnabled(Sub::Ready));
        assert_eq!(status(&n, MTR, true, false), (0x13, 0x85));
    }

    #[test]
    fn homing_aborted_by_halt_and_homing_priority_over_start() {
        let mut m = enabled(Variant::Emca, 0x03);
        let cond = Conditions {
            motion_complete: false,
            ..Conditions::healthy()
        };
        // START and HOM together: homing wins on the EMCA.
        let (n, a) = m.step(Variant::Emca, ctl(0x03, 0x07), &cond);
        assert_eq!(a.command, Some(Command::StartHoming));
        m = n;
        let (n, a) = m.step(Variant::Emca, ctl(0x03, 0x04), &cond);
        assert_eq!(a.transition, Some(Transition::TA8));
        assert_eq!(a.command, Some(Command::Halt));
        assert_eq!(n.state, State::OperationEnabled(Sub::Ready));
        // The CMMO-ST reports two edges in one cycle (3Ch) and starts neither.
        let m = enabled(Variant::CmmoSt, 0x23);
        let (n, a) = m.step(Variant::CmmoSt, ctl(0x23, 0x07), &cond);
        assert_eq!(a.refusal, Some(Refusal::SimultaneousStarts));
        assert_eq!(n.state, State::OperationEnabled(Sub::Ready));
    }

    #[test]
    fn direct_positioning_sequence_tab_5_13() {
        let mut m = enabled(MTR, 0x43);
        let mut cond = Conditions {
            referenced: true,
            ..Conditions::healthy()
        };
        assert_eq!(status(&m, MTR, true, false), (0x53, 0x85));
        // START↑: ACK = 1, MC = 0: SPOS 0x83.
        let (n, a) = m.step(MTR, ctl(0x43, 0x03), &cond);
        assert_eq!(
            (a.transition, a.command),
            (Some(Transition::TA1), Some(Command::StartTask))
        );
        m = n;
        assert_eq!(status(&m, MTR, true, false), (0x53, 0x83));
        cond.motion_complete = false;
        let (n, _) = m.step(MTR, ctl(0x43, 0x03), &cond);
        m = n;
        assert_eq!(status(&m, MTR, true, true).1, 0x93);
        // START released, still moving: ACK falls.
        let (n, _) = m.step(MTR, ctl(0x43, 0x01), &cond);
        m = n;
        assert_eq!(status(&m, MTR, true, true).1, 0x91);
        // Done: SPOS 0x85 (TA2).
        cond.motion_complete = true;
        let (n, a) = m.step(MTR, ctl(0x43, 0x01), &cond);
        assert_eq!(a.transition, Some(Transition::TA2));
        assert_eq!(status(&n, MTR, true, false), (0x53, 0x85));
    }

    #[test]
    fn cmmo_st_homing_and_record_sequence_tab_5_5_to_5_10() {
        let v = Variant::CmmoSt;
        let mut m = enabled(v, 0x23);
        assert_eq!(status(&m, v, false, false), (0x13, 0x05));
        let running = Conditions {
            motion_complete: false,
            ..Conditions::healthy()
        };
        // 4.1 HOM P (CPOS 0x05): ACK = 1, MC = 0; 4.2 running: SPOS 0x13.
        m = m.step(v, ctl(0x23, 0x05), &running).0;
        assert_eq!(status(&m, v, false, true).1, 0x13);
        // 4.3 homing done while HOM is still held: 0x87; HOM released: 0x85.
        let homed = Conditions {
            referenced: true,
            ..Conditions::healthy()
        };
        m = m.step(v, ctl(0x23, 0x05), &homed).0;
        assert_eq!(status(&m, v, true, false).1, 0x87);
        m = m.step(v, ctl(0x23, 0x01), &homed).0;
        assert_eq!(status(&m, v, true, false).1, 0x85);
        // 5.2 START P (CPOS 0x03): ACK = 1, MC = 0 → 0x83.
        let (n, a) = m.step(v, ctl(0x23, 0x03), &homed);
        assert_eq!(a.command, Some(Command::StartTask));
        m = n;
        assert_eq!(status(&m, v, true, false).1, 0x83);
        // 5.3 running, START back to 0: MOV = 1, ACK = 0.
        let moving = Conditions {
            motion_complete: false,
            ..homed
        };
        m = m.step(v, ctl(0x23, 0x01), &moving).0;
        assert_eq!(status(&m, v, true, true).1, 0x91);
        // 5.4 done: 0x85.
        m = m.step(v, ctl(0x23, 0x01), &homed).0;
        assert_eq!(status(&m, v, true, false), (0x13, 0x85));
    }

    #[test]
    fn start_refusals() {
        let m = enabled(MTR, 0x03);
        let (n, a) = m.step(MTR, ctl(0x03, 0x03), &Conditions::healthy());
        assert_eq!(a.refusal, Some(Refusal::NotReferenced));
        assert_eq!(n.state, State::OperationEnabled(Sub::Ready));
        assert!(!n.ack);
        let cond = Conditions {
            referenced: true,
            task_valid: false,
            ..Conditions::healthy()
        };
        let (_, a) = m.step(MTR, ctl(0x03, 0x03), &cond);
        assert_eq!(a.refusal, Some(Refusal::InvalidTask));
        // START with HALT = 0 (`0xx0.00P1` needs HALT = 1) is no start at all.
        let (n, a) = m.step(MTR, ctl(0x03, 0x02), &cond);
        assert_eq!(a, Actions::default());
        assert_eq!(n.state, State::OperationEnabled(Sub::Ready));
    }

    #[test]
    fn halt_resume_and_clear_emca_p178() {
        let v = Variant::Emca;
        let mut m = enabled(v, 0x03);
        let mut cond = Conditions {
            referenced: true,
            ..Conditions::healthy()
        };
        let (n, _) = m.step(v, ctl(0x03, 0x03), &cond);
        cond.motion_complete = false;
        let (n, _) = n.step(v, ctl(0x03, 0x01), &cond);
        m = n;
        // HALT 1→0: TA3, SPOS 0001.0000 while braking, then 0000.0000.
        let (n, a) = m.step(v, ctl(0x03, 0x00), &cond);
        assert_eq!(
            (a.transition, a.command),
            (Some(Transition::TA3), Some(Command::Halt))
        );
        assert_eq!(n.spos(true, false, false, false).to_byte(), 0b0001_0000);
        assert_eq!(n.spos(false, false, false, false).to_byte(), 0);
        m = n;
        // Continue: HALT = 1, then START P → ACK (0000.0011).
        let (n, _) = m.step(v, ctl(0x03, 0x01), &cond);
        let (n, a) = n.step(v, ctl(0x03, 0x03), &cond);
        assert_eq!(
            (a.transition, a.command),
            (Some(Transition::TA4), Some(Command::Resume))
        );
        assert_eq!(n.spos(false, false, false, false).to_byte(), 0b0000_0011);
        m = n;
        // Halt again, then CLEAR P: TA6 → Ready; MC once at rest.
        let (n, _) = m.step(v, ctl(0x03, 0x00), &cond);
        let (n, a) = n.step(v, ctl(0x03, 0x40), &cond);
        assert_eq!(
            (a.transition, a.command),
            (Some(Transition::TA6), Some(Command::Clear))
        );
        assert_eq!(n.state, State::OperationEnabled(Sub::Ready));
        cond.motion_complete = true;
        let (n, _) = n.step(v, ctl(0x03, 0x01), &cond);
        assert!(n.mc);
    }

    #[test]
    fn halt_ends_speed_and_force_tasks() {
        let v = Variant::CmmoSt;
        let m = enabled(v, 0x43);
        let mut cond = Conditions {
            referenced: true,
            task_mode: ControlMode::Force,
            ..Conditions::healthy()
        };
        let (n, _) = m.step(v, ctl(0x43, 0x03), &cond);
        cond.motion_complete = false;
        let (n, a) = n.step(v, ctl(0x43, 0x00), &cond);
        assert_eq!(
            (a.transition, a.command),
            (Some(Transition::TA2), Some(Command::Halt))
        );
        assert_eq!(n.state, State::OperationEnabled(Sub::Ready));
    }

    #[test]
    fn new_task_while_running_follows_the_start_condition() {
        let v = Variant::CmmoSt;
        let base = Conditions {
            referenced: true,
            ..Conditions::healthy()
        };
        let running = {
            let m = enabled(v, 0x63);
            let (n, _) = m.step(v, ctl(0x63, 0x03), &base);
            let c = Conditions {
                motion_complete: false,
                ..base
            };
            n.step(v, ctl(0x63, 0x01), &c).0
        };
        for (sc, want) in [
            (StartCondition::Ignore, None),
            (StartCondition::Interrupt, Some(Command::StartTask)),
            (StartCondition::Wait, Some(Command::QueueTask)),
        ] {
            let c = Conditions {
                motion_complete: false,
                start_condition: sc,
                ..base
            };
            let (n, a) = running.step(v, ctl(0x63, 0x03), &c);
            assert_eq!(a.command, want, "{sc:?}");
            assert_eq!(n.ack, want.is_some());
        }
        // The MTR-DCI's record select has no TA5 (b), whatever the condition says.
        let m = enabled(MTR, 0x03);
        let (n, _) = m.step(MTR, ctl(0x03, 0x03), &base);
        let c = Conditions {
            motion_complete: false,
            start_condition: StartCondition::Interrupt,
            ..base
        };
        let n = n.step(MTR, ctl(0x03, 0x01), &c).0;
        let (_, a) = n.step(MTR, ctl(0x03, 0x03), &c);
        assert_eq!(a.command, None);
    }

    #[test]
    fn record_chain_continues_without_start() {
        let v = Variant::Emca;
        let base = Conditions {
            referenced: true,
            ..Conditions::healthy()
        };
        let (n, _) = enabled(v, 0x03).step(v, ctl(0x03, 0x03), &base);
        let chain = Conditions {
            chain_continues: true,
            ..base
        };
        let (n, a) = n.step(v, ctl(0x03, 0x01), &chain);
        assert_eq!(
            (a.transition, a.command),
            (Some(Transition::TA5), Some(Command::NextRecord))
        );
        assert_eq!(n.state, State::OperationEnabled(Sub::Positioning));
        assert!(!n.mc);
        let (n, a) = n.step(v, ctl(0x03, 0x01), &base);
        assert_eq!(a.transition, Some(Transition::TA2));
        assert!(n.mc);
    }

    #[test]
    fn jog_both_directions_and_halt_ends_jog() {
        let v = Variant::Emca;
        let m = enabled(v, 0x03);
        let moving = Conditions {
            motion_complete: false,
            ..Conditions::healthy()
        };
        // Jogging: CPOS 0xx0.1001 → SPOS 0001.0011 (ACK, MOV, HALT).
        let (n, a) = m.step(v, ctl(0x03, 0b0000_1001), &moving);
        assert_eq!(a.transition, Some(Transition::TA9));
        assert_eq!(n.spos(true, false, false, false).to_byte(), 0b0001_0011);
        assert_eq!(n.state.number(), 4);
        assert_eq!(n.state, State::OperationEnabled(Sub::JogPositive));
        let (n, a) = n.step(v, ctl(0x03, 0x01), &moving);
        assert_eq!(
            (a.transition, a.command),
            (Some(Transition::TA10), Some(Command::StopJog))
        );
        assert!(!n.ack && !n.mc);
        let (n, _) = n.step(v, ctl(0x03, 0x01), &Conditions::healthy());
        assert!(n.mc);
        let (n, a) = n.step(v, ctl(0x03, 0b0001_0001), &moving);
        assert_eq!(a.command, Some(Command::StartJog(Direction::Negative)));
        let (_, a) = n.step(v, ctl(0x03, 0b0001_0000), &moving);
        assert_eq!(a.transition, Some(Transition::TA12));
        // Both jog bits rising together start nothing.
        let (_, a) = m.step(v, ctl(0x03, 0b0001_1001), &moving);
        assert_eq!(a.transition, None);
        assert_eq!(Sub::JogPositive.number(Variant::CmmoSt), 4);
        assert_eq!(Sub::Homing.number(Variant::CmmoSt), 6);
        assert_eq!(Sub::Homing.number(MTR), 4);
    }

    #[test]
    fn teach_handshake_per_variant() {
        // EMCA/CMMO-ST: TEACH P → SPOS.TEACH = 1; TEACH N → capture, SPOS.TEACH = 0.
        let v = Variant::Emca;
        let m = enabled(v, 0x03);
        let c = Conditions::healthy();
        let (n, a) = m.step(v, ctl(0x03, 0x21), &c);
        assert!(!a.teach_capture);
        assert_eq!(n.spos(false, false, false, false).to_byte(), 0b0000_1101);
        let (n, a) = n.step(v, ctl(0x03, 0x01), &c);
        assert!(a.teach_capture);
        assert_eq!(n.spos(false, false, false, false).to_byte(), 0b0000_0101);
        // MTR-DCI: SPOS.TEACH = 1 "value transferred" after the falling edge.
        let m = enabled(MTR, 0x03);
        let (n, _) = m.step(MTR, ctl(0x03, 0x21), &c);
        assert!(!n.teach);
        let (n, a) = n.step(MTR, ctl(0x03, 0x01), &c);
        assert!(a.teach_capture && n.teach);
        let (n, _) = n.step(MTR, ctl(0x03, 0x21), &c);
        assert!(!n.teach);
    }

    #[test]
    fn stop_goes_to_s3_with_quick_stop_and_mc_once_stopped() {
        // Tab. 5/14 row 7.7: CCON 0x41 → SCON 0x51, MC = 1 once stopped.
        let m = enabled(MTR, 0x43);
        let moving = Conditions {
            referenced: true,
            motion_complete: false,
            ..Conditions::healthy()
        };
        let (n, _) = m.step(MTR, ctl(0x43, 0x03), &moving);
        let (n, a) = n.step(MTR, ctl(0x41, 0x03), &moving);
        assert_eq!(
            (a.transition, a.command),
            (Some(Transition::T4), Some(Command::QuickStop))
        );
        assert_eq!(n.state, State::DriveEnabled);
        assert!(!n.mc);
        let stopped = Conditions {
            referenced: true,
            ..Conditions::healthy()
        };
        let (n, _) = n.step(MTR, ctl(0x41, 0x01), &stopped);
        assert_eq!(n.scon(MTR, false, true, false).to_byte(), 0x51);
        assert!(n.mc);
    }

    #[test]
    fn fault_and_acknowledge_per_variant() {
        let fault = |class| Conditions {
            new_fault: Some(class),
            ..Conditions::healthy()
        };
        let cause = Conditions {
            fault_cause_present: true,
            ..Conditions::healthy()
        };
        let ok = Conditions::healthy();
        for v in [Variant::MtrDci, Variant::Emca, Variant::CmmoSt] {
            for class in [FaultClass::Serious, FaultClass::Simple] {
                let m = enabled(v, 0x03);
                let (n, a) = m.step(v, ctl(0x03, 0x01), &fault(class));
                assert_eq!(
                    (a.transition, a.command),
                    (Some(Transition::T7), Some(Command::FaultReaction))
                );
                assert_eq!(n.state, State::FaultReaction);
                assert_eq!(n.scon(v, false, true, false).fault, v != Variant::CmmoSt);
                assert!(!n.mc);
                let (n, a) = n.step(v, ctl(0x03, 0x01), &cause);
                assert_eq!(a.transition, Some(Transition::T8));
                assert!(n.scon(v, false, true, false).fault);
                // RESET P while the cause is present: T11.
                let (n, a) = n.step(v, ctl(0x0B, 0x01), &cause);
                assert_eq!(a.transition, Some(Transition::T11));
                assert!(!a.acknowledge);
                // RESET P with ENABLE = 1, cause gone.
                let (n2, a) = n
                    .step(v, ctl(0x03, 0x01), &ok)
                    .0
                    .step(v, ctl(0x0B, 0x01), &ok);
                let expect = match (v, class) {
                    (_, FaultClass::Simple) => Some((Transition::T10, State::DriveEnabled)),
                    (Variant::MtrDci, FaultClass::Serious) => {
                        Some((Transition::T9, State::DriveBlocked))
                    }
                    (_, FaultClass::Serious) => None,
                };
                match expect {
                    Some((t, s)) => {
                        assert_eq!(a.transition, Some(t), "{v:?} {class:?}");
                        assert_eq!(n2.state, s);
                        assert!(a.acknowledge && n2.mc);
                        // After the acknowledge FAULT is 0 and MC is 1.
                        assert!(!n2.scon(v, false, true, false).fault);
                    }
                    None => assert_eq!(n2.state, State::Fault, "{v:?} {class:?}"),
                }
                // ENABLE = 0 with RESET P always acknowledges (T9), the host's safe rule.
                // (On the MTR-DCI the ENABLE falling edge already acknowledges.)
                let (n3, a1) = n.step(v, ctl(0x00, 0x01), &ok);
                let (n3, a2) = n3.step(v, ctl(0x08, 0x01), &ok);
                let t9 = [a1.transition, a2.transition];
                let want = if v == MTR {
                    [Some(Transition::T9), None]
                } else {
                    [None, Some(Transition::T9)]
                };
                assert_eq!(t9, want, "{v:?} {class:?}");
                assert_eq!(n3.state, State::DriveBlocked);
            }
        }
        // MTR-DCI: an ENABLE falling edge acknowledges too (§5.5.7 ex. 3.4).
        let m = enabled(MTR, 0x03);
        let (n, _) = m.step(MTR, ctl(0x03, 0x01), &fault(FaultClass::Simple));
        let (n, _) = n.step(MTR, ctl(0x03, 0x01), &ok);
        let (n, a) = n.step(MTR, ctl(0x00, 0x01), &ok);
        assert_eq!(a.transition, Some(Transition::T9));
        assert_eq!(n.state, State::DriveBlocked);
    }

    #[test]
    fn a_higher_priority_fault_re_enters_s5_from_s6() {
        let m = enabled(MTR, 0x03);
        let f = Conditions {
            new_fault: Some(FaultClass::Simple),
            ..Conditions::healthy()
        };
        let (n, _) = m.step(MTR, ctl(0x03, 0x01), &f);
        let (n, _) = n.step(MTR, ctl(0x03, 0x01), &Conditions::healthy());
        assert_eq!(n.state, State::Fault);
        let f2 = Conditions {
            new_fault: Some(FaultClass::Serious),
            ..Conditions::healthy()
        };
        let (n, a) = n.step(MTR, ctl(0x03, 0x01), &f2);
        assert_eq!(a.transition, Some(Transition::T7));
        assert_eq!(n.state, State::FaultReaction);
        assert_eq!(n.fault_class, FaultClass::Serious);
    }

    #[test]
    fn opm_changes_only_in_s2_s3_sa1() {
        let mut m = enabled(MTR, 0x03);
        let cond = Conditions {
            referenced: true,
            motion_complete: false,
            ..Conditions::healthy()
        };
        let (n, _) = m.step(MTR, ctl(0x03, 0x03), &cond);
        m = n;
        let (n, _) = m.step(MTR, ctl(0x43, 0x01), &cond);
        assert_eq!(n.opm, Opm::RecordSelect);
        let done = Conditions {
            referenced: true,
            ..Conditions::healthy()
        };
        let (n, _) = n.step(MTR, ctl(0x43, 0x01), &done);
        assert_eq!(n.state, State::OperationEnabled(Sub::Ready));
        assert_eq!(n.opm, Opm::Direct);
        // Reserved modes are not taken over.
        let (n, _) = n.step(MTR, ctl(0x83, 0x01), &done);
        assert_eq!(n.opm, Opm::Direct);
    }

    #[test]
    fn bring_up_reaches_operation_enabled_from_a_fault() {
        for v in [Variant::MtrDci, Variant::Emca, Variant::CmmoSt] {
            for class in [FaultClass::Serious, FaultClass::Simple] {
                let mut m = enabled(v, 0x03);
                let f = Conditions {
                    new_fault: Some(class),
                    ..Conditions::healthy()
                };
                let mut last = Ccon::from_byte(0x03);
                m = m
                    .step(
                        v,
                        Control {
                            ccon: last,
                            cpos: Cpos::idle(),
                        },
                        &f,
                    )
                    .0;
                let mut ready = false;
                for _ in 0..12 {
                    let scon = m.scon(v, false, true, false);
                    let c = match bring_up(scon, last, Opm::Direct) {
                        BringUp::Ready(_) => {
                            ready = true;
                            break;
                        }
                        BringUp::Send(c) => c,
                        BringUp::Blocked(b) => panic!("{b:?}"),
                    };
                    assert!(c.lock);
                    m = m
                        .step(
                            v,
                            Control {
                                ccon: c,
                                cpos: Cpos::idle(),
                            },
                            &Conditions::healthy(),
                        )
                        .0;
                    last = c;
                }
                assert!(ready, "{v:?} {class:?}: {:?}", m.state);
                assert_eq!(m.opm, Opm::Direct);
            }
        }
        let s = Scon::from_byte(0x30);
        assert_eq!(
            bring_up(s, Ccon::default(), Opm::RecordSelect),
            BringUp::Blocked(BringUpBlock::FctHasControl)
        );
        assert_eq!(
            bring_up(Scon::default(), Ccon::default(), Opm::RecordSelect),
            BringUp::Blocked(BringUpBlock::NoLoadVoltage)
        );
    }

    #[test]
    fn handshake_against_the_state_machine() {
        let v = Variant::CmmoSt;
        let mut m = enabled(v, 0x23);
        let mut hs = StartHandshake::new(50);
        hs.request();
        let mut remaining = 3; // cycles of motion after the start
        let mut seen = heapless::Vec::<HandshakePhase, 16>::new();
        for _ in 0..20 {
            let scon = m.scon(v, false, true, false);
            let spos = m.spos(remaining > 0 && !m.mc, false, false, true);
            let p = hs.poll(scon, spos);
            if seen.last() != Some(&p) {
                seen.push(p).unwrap();
            }
            if p == HandshakePhase::Complete {
                break;
            }
            let cpos = Cpos {
                start: hs.start_bit(),
                ..Cpos::idle()
            };
            let started = m.state == State::OperationEnabled(Sub::Positioning);
            if started {
                remaining -= 1;
            }
            let cond = Conditions {
                referenced: true,
                motion_complete: started && remaining <= 0,
                ..Conditions::healthy()
            };
            m = m
                .step(
                    v,
                    Control {
                        ccon: Ccon::from_byte(0x23),
                        cpos,
                    },
                    &cond,
                )
                .0;
        }
        assert_eq!(
            seen.as_slice(),
            &[
                HandshakePhase::Raised,
                HandshakePhase::Acknowledged,
                HandshakePhase::Running,
                HandshakePhase::Complete
            ]
        );
    }

    #[test]
    fn handshake_ignores_a_stale_mc_and_times_out() {
        let scon = Scon::from_byte(0x13);
        let mut hs = StartHandshake::new(3);
        hs.request();
        // MC = 1 of the previous task, ACK = 0: not completion.
        assert_eq!(hs.poll(scon, Spos::from_byte(0x85)), HandshakePhase::Raised);
        assert!(hs.start_bit());
        assert_eq!(hs.poll(scon, Spos::from_byte(0x85)), HandshakePhase::Raised);
        assert_eq!(hs.poll(scon, Spos::from_byte(0x85)), HandshakePhase::Raised);
        assert_eq!(
            hs.poll(scon, Spos::from_byte(0x85)),
            HandshakePhase::TimedOut
        );
        let mut hs = StartHandshake::new(0);
        hs.request();
        hs.poll(scon, Spos::from_byte(0x85));
        assert_eq!(
            hs.poll(Scon::from_byte(0x18), Spos::from_byte(0x81)),
            HandshakePhase::Failed
        );
        // CMMO-ST homing done image 0x87 (ACK and MC together) is completion.
        let mut hs = StartHandshake::new(0);
        hs.request();
        hs.poll(scon, Spos::from_byte(0x05));
        assert_eq!(
            hs.poll(scon, Spos::from_byte(0x87)),
            HandshakePhase::Complete
        );
    }

    #[test]
    fn spos_edges_and_observed_state() {
        let e = SposEdges::between(Spos::from_byte(0x05), Spos::from_byte(0x03));
        assert!(e.ack_rise && e.mc_fall && !e.mc_rise && !e.ack_fall);
        let e = SposEdges::between(Spos::from_byte(0x11), Spos::from_byte(0x85));
        assert!(e.mc_rise && e.ref_rise);
        assert_eq!(
            State::observe(Scon::from_byte(0x13), Spos::from_byte(0x85)),
            State::OperationEnabled(Sub::Ready)
        );
        assert_eq!(
            State::observe(Scon::from_byte(0x13), Spos::from_byte(0x00)),
            State::OperationEnabled(Sub::Halted)
        );
        assert_eq!(
            State::observe(Scon::from_byte(0x51), Spos::from_byte(0x85)),
            State::DriveEnabled
        );
        assert_eq!(
            State::observe(Scon::from_byte(0x18), Spos::from_byte(0x00)),
            State::Fault
        );
        assert_eq!(
            State::observe(Scon::from_byte(0x10), Spos::from_byte(0x04)),
            State::DriveBlocked
        );
    }

    fn any_conditions() -> impl Strategy<Value = Conditions> {
        (
            proptest::option::weighted(
                0.05,
                prop_oneof![Just(FaultClass::Serious), Just(FaultClass::Simple)],
            ),
            any::<[bool; 8]>(),
            0u8..4,
        )
            .prop_map(|(new_fault, b, sc)| Conditions {
                new_fault,
                fault_cause_present: b[0],
                reaction_done: b[1],
                load_voltage: b[2] || b[3],
                fieldbus_control: true,
                enable_permitted: b[4] || b[3],
                referenced: b[5],
                motion_complete: b[6],
                task_valid: true,
                chain_continues: b[7],
                start_condition: StartCondition::from_bits(sc),
                task_mode: ControlMode::from_bits(sc),
            })
    }

    proptest! {
        /// Under fieldbus control, no control sequence reaches or stays in "Operation enabled"
        /// without ENABLE = 1 and STOP = 1 in that cycle's CCON.
        #[test]
        fn operation_enabled_needs_enable_and_stop(
            v in prop_oneof![Just(Variant::MtrDci), Just(Variant::Emca), Just(Variant::CmmoSt)],
            steps in proptest::collection::vec((any::<u8>(), any::<u8>(), any_conditions()), 1..64),
        ) {
            let mut m = Machine::power_on();
            for (ccon, cpos, cond) in steps {
                let c = Control::from_bytes(ccon, cpos);
                let (n, a) = m.step(v, c, &cond);
                if let State::OperationEnabled(_) = n.state {
                    prop_assert!(c.ccon.enable && c.ccon.stop, "{:?} -> {:?} with CCON {:#04x}", m.state, n.state, ccon);
                }
                // A task never starts outside S4.
                if matches!(a.command, Some(Command::StartTask | Command::StartHoming | Command::StartJog(_))) {
                    prop_assert!(matches!(n.state, State::OperationEnabled(_)));
                }
                m = n;
            }
        }
    }
}
