//! The CiA 402 device state machine ("power drive system" FSA): the eight states, the numbered
//! transitions as one `match` ([`next`]), the statusword pattern of each state, the master-side
//! decoding with the standard masks ([`State::from_statusword`]) and the controlword that moves one
//! step toward Operation enabled ([`next_controlword`]).
//!
//! Transition numbers are those of CiA 402 and the TLC5xx manual (§5.2.1); the MTR-DCI adds its
//! own 19, 20 and 21 (§C.2) when the profile's [`Flavour`] is [`Flavour::FestoMtrDci`].
//!
//! ```
//! use drivers::cia402::{TLC5XX, controlword::Controlword, state::{DeviceStateMachine, State}};
//! let mut fsa = DeviceStateMachine::new(TLC5XX);
//! fsa.set_self_test_done(true);
//! fsa.handle_controlword(Controlword(0x0006));
//! fsa.handle_controlword(Controlword(0x000F)); // Tr.3 + Tr.4 from Ready to switch on
//! assert_eq!(fsa.state(), State::OperationEnabled);
//! assert_eq!(fsa.statusword().0, 0x0027);
//! ```

use super::DeviceProfile;
use super::controlword::{Command, Controlword};
use super::statusword::Statusword;
use heapless::Vec;

/// The states of the CiA 402 device state machine (TLC5xx `driveStat` codes 2..9).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum State {
    /// Not ready to switch on (TLC code 2, MTR-DCI B): initialising, self test.
    NotReadyToSwitchOn,
    /// Switch on disabled (3, C): power section off, waiting for Shutdown.
    SwitchOnDisabled,
    /// Ready to switch on (4, D).
    ReadyToSwitchOn,
    /// Switched on (5, E): amplifier on, no motion.
    SwitchedOn,
    /// Operation enabled (6, F): the operation mode runs.
    OperationEnabled,
    /// Quick stop active (7, G).
    QuickStopActive,
    /// Fault reaction active (8, H): stopping after a fault.
    FaultReactionActive,
    /// Fault (9, I): waiting for a fault reset edge.
    Fault,
}

/// The numbered transitions (CiA 402 / TLC5xx §5.2.1; 19, 20, 21 are the MTR-DCI's, §C.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Transition {
    /// 1: Not ready to switch on → Switch on disabled, automatic after the self test.
    T1,
    /// 2: Switch on disabled → Ready to switch on, Shutdown.
    T2,
    /// 3: Ready to switch on → Switched on, Switch on (amplifier on).
    T3,
    /// 4: Switched on → Operation enabled, Enable operation.
    T4,
    /// 5: Operation enabled → Switched on, Disable operation (motion aborted).
    T5,
    /// 6: Switched on → Ready to switch on, Shutdown (amplifier off).
    T6,
    /// 7: Ready to switch on → Switch on disabled, Quick stop or Disable voltage.
    T7,
    /// 8: Operation enabled → Ready to switch on, Shutdown (amplifier off at once).
    T8,
    /// 9: Operation enabled → Switch on disabled, Disable voltage.
    T9,
    /// 10: Switched on → Switch on disabled, Disable voltage or Quick stop.
    T10,
    /// 11: Operation enabled → Quick stop active, Quick stop.
    T11,
    /// 12: Quick stop active → Switch on disabled: Disable voltage, or the stop completed with a
    /// quick stop option that leaves the state.
    T12,
    /// 13: any state → Fault reaction active, a fault was signalled.
    T13,
    /// 14: Fault reaction active → Fault, the reaction completed.
    T14,
    /// 15: Fault → Switch on disabled, fault reset rising edge with the cause removed.
    T15,
    /// 16: Quick stop active → Operation enabled, Enable operation (the interrupted command goes on).
    T16,
    /// 19 (MTR-DCI): Fault → Switched on, fault reset edge with bits 0..3 all set.
    T19,
    /// 20 (MTR-DCI): Not ready to switch on → Ready to switch on, Shutdown after the self test.
    T20,
    /// 21 (MTR-DCI, CiA 402 ≥ 2.1.10): Ready to switch on → Operation enabled, Enable operation.
    T21,
}

impl Transition {
    /// The transition's number in the manuals' tables.
    pub const fn number(self) -> u8 {
        match self {
            Transition::T1 => 1,
            Transition::T2 => 2,
            Transition::T3 => 3,
            Transition::T4 => 4,
            Transition::T5 => 5,
            Transition::T6 => 6,
            Transition::T7 => 7,
            Transition::T8 => 8,
            Transition::T9 => 9,
            Transition::T10 => 10,
            Transition::T11 => 11,
            Transition::T12 => 12,
            Transition::T13 => 13,
            Transition::T14 => 14,
            Transition::T15 => 15,
            Transition::T16 => 16,
            Transition::T19 => 19,
            Transition::T20 => 20,
            Transition::T21 => 21,
        }
    }
}

/// Which transition table a device follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Flavour {
    /// CiA 402 as the TLC5xx implements it: 1 and 2 to reach Ready to switch on; Enable operation
    /// from Ready to switch on runs 3 then 4 (the manual's traces send 000Fh there).
    Cia402,
    /// The MTR-DCI (§C.2): 20 replaces 1 + 2 from Not ready to switch on, 21 replaces 3 + 4, and a
    /// fault reset with bits 0..3 set goes to Switched on (19) so a load is not dropped.
    FestoMtrDci,
}

/// What the device does once a quick stop has stopped the axis (CiA 402 605Ah classes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum QuickStopOption {
    /// 605Ah = 1..4: leave to Switch on disabled when the stop completes (transition 12).
    ToSwitchOnDisabled,
    /// 605Ah = 5..8: stay in Quick stop active; Enable operation resumes (16), Disable voltage
    /// leaves (12). Both reference devices behave like this ("no automatic exit from state 7").
    StayInQuickStop,
}

impl QuickStopOption {
    /// The class of a 605Ah quick stop option code (0 and 1..4 leave, 5..8 stay); `None` for
    /// codes CiA 402 does not define for this purpose (negative codes are manufacturer specific).
    pub const fn from_code(code: i16) -> Option<QuickStopOption> {
        match code {
            0..=4 => Some(QuickStopOption::ToSwitchOnDisabled),
            5..=8 => Some(QuickStopOption::StayInQuickStop),
            _ => None,
        }
    }
}

/// How the Fault state is shown in the statusword.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FaultCoding {
    /// CiA 402: Fault = `x0xx 1000` (0008h). The default for both devices.
    Dsp402,
    /// The TLC5xx manual as printed (§5.2.3, erratum A2): `x0x1111` (000Fh), which a CiA 402
    /// master reads as Fault reaction active. The master tests bit 3 either way.
    AsPrinted,
}

/// The inputs of a transition other than the controlword: what the device itself knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Conditions {
    /// The self test is done (transitions 1 / 20).
    pub self_test_done: bool,
    /// A fault cause is present (transition 13; blocks 15 and 19 until removed).
    pub fault: bool,
    /// The fault reaction has finished (transition 14).
    pub fault_reaction_done: bool,
    /// The quick stop has brought the axis to standstill (transition 12 for
    /// [`QuickStopOption::ToSwitchOnDisabled`]).
    pub quick_stop_done: bool,
    /// Controlword bit 7 rose since the previous controlword (transitions 15 / 19).
    pub fault_reset_edge: bool,
}

/// One step of the state machine: the state reached from `state` under `cw` and `c`, and the
/// transition taken (`None`: the state stays). The table of the manuals, in one `match`.
pub fn next(
    state: State,
    cw: Controlword,
    c: &Conditions,
    profile: &DeviceProfile,
) -> (State, Option<Transition>) {
    use Command::*;
    use State::*;
    use Transition::*;
    let festo = matches!(profile.flavour, Flavour::FestoMtrDci);
    let stays = matches!(profile.quick_stop, QuickStopOption::StayInQuickStop);
    let (to, tr) = match (state, cw.command()) {
        // 13: a fault preempts every command, from every state but the fault states.
        (s, _) if c.fault && !matches!(s, FaultReactionActive | Fault) => {
            (FaultReactionActive, T13)
        }
        (NotReadyToSwitchOn, Shutdown) if festo && c.self_test_done => (ReadyToSwitchOn, T20),
        (NotReadyToSwitchOn, _) if !festo && c.self_test_done => (SwitchOnDisabled, T1),
        (SwitchOnDisabled, Shutdown) => (ReadyToSwitchOn, T2),
        (ReadyToSwitchOn, SwitchOn) => (SwitchedOn, T3),
        (ReadyToSwitchOn, EnableOperation) if festo => (OperationEnabled, T21),
        // The TLC5xx passes Switched on on its way (3, then 4 on the next evaluation).
        (ReadyToSwitchOn, EnableOperation) => (SwitchedOn, T3),
        (ReadyToSwitchOn, DisableVoltage | QuickStop) => (SwitchOnDisabled, T7),
        (SwitchedOn, EnableOperation) => (OperationEnabled, T4),
        (SwitchedOn, Shutdown) => (ReadyToSwitchOn, T6),
        (SwitchedOn, DisableVoltage | QuickStop) => (SwitchOnDisabled, T10),
        (OperationEnabled, SwitchOn) => (SwitchedOn, T5),
        (OperationEnabled, Shutdown) => (ReadyToSwitchOn, T8),
        (OperationEnabled, DisableVoltage) => (SwitchOnDisabled, T9),
        (OperationEnabled, QuickStop) => (QuickStopActive, T11),
        (QuickStopActive, DisableVoltage) => (SwitchOnDisabled, T12),
        (QuickStopActive, _) if !stays && c.quick_stop_done => (SwitchOnDisabled, T12),
        (QuickStopActive, EnableOperation) if stays => (OperationEnabled, T16),
        (FaultReactionActive, _) if c.fault_reaction_done => (Fault, T14),
        (Fault, EnableOperation) if festo && c.fault_reset_edge && !c.fault => (SwitchedOn, T19),
        (Fault, _) if c.fault_reset_edge && !c.fault => (SwitchOnDisabled, T15),
        (s, _) => return (s, None),
    };
    (to, Some(tr))
}

/// Whether the transition table contains `tr` from `from` to `to` for `flavour`: the reference the
/// tests hold [`next`] against.
pub const fn allowed(from: State, to: State, tr: Transition, flavour: Flavour) -> bool {
    use State::*;
    use Transition::*;
    let festo = matches!(flavour, Flavour::FestoMtrDci);
    match tr {
        T1 => matches!((from, to), (NotReadyToSwitchOn, SwitchOnDisabled)) && !festo,
        T2 => matches!((from, to), (SwitchOnDisabled, ReadyToSwitchOn)),
        T3 => matches!((from, to), (ReadyToSwitchOn, SwitchedOn)),
        T4 => matches!((from, to), (SwitchedOn, OperationEnabled)),
        T5 => matches!((from, to), (OperationEnabled, SwitchedOn)),
        T6 => matches!((from, to), (SwitchedOn, ReadyToSwitchOn)),
        T7 => matches!((from, to), (ReadyToSwitchOn, SwitchOnDisabled)),
        T8 => matches!((from, to), (OperationEnabled, ReadyToSwitchOn)),
        T9 => matches!((from, to), (OperationEnabled, SwitchOnDisabled)),
        T10 => matches!((from, to), (SwitchedOn, SwitchOnDisabled)),
        T11 => matches!((from, to), (OperationEnabled, QuickStopActive)),
        T12 => matches!((from, to), (QuickStopActive, SwitchOnDisabled)),
        T13 => !matches!(from, FaultReactionActive | Fault) && matches!(to, FaultReactionActive),
        T14 => matches!((from, to), (FaultReactionActive, Fault)),
        T15 => matches!((from, to), (Fault, SwitchOnDisabled)),
        T16 => matches!((from, to), (QuickStopActive, OperationEnabled)),
        T19 => matches!((from, to), (Fault, SwitchedOn)) && festo,
        T20 => matches!((from, to), (NotReadyToSwitchOn, ReadyToSwitchOn)) && festo,
        T21 => matches!((from, to), (ReadyToSwitchOn, OperationEnabled)) && festo,
    }
}

/// Why a statusword does not name a state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum StateError {
    /// Bits 0..3, 5, 6 form no pattern of the CiA 402 table (the raw statusword is given).
    #[error("statusword {0:#06x} shows no CiA 402 state (bits 6,5,3..0 = {1:#04x})")]
    UndefinedPattern(u16, u16),
}

impl State {
    /// The state's name as CiA 402 writes it, for people.
    pub const fn name(self) -> &'static str {
        match self {
            State::NotReadyToSwitchOn => "Not ready to switch on",
            State::SwitchOnDisabled => "Switch on disabled",
            State::ReadyToSwitchOn => "Ready to switch on",
            State::SwitchedOn => "Switched on",
            State::OperationEnabled => "Operation enabled",
            State::QuickStopActive => "Quick stop active",
            State::FaultReactionActive => "Fault reaction active",
            State::Fault => "Fault",
        }
    }

    /// The state bits (0..3, 5, 6) the device shows in this state. Fault follows `coding`.
    pub const fn pattern(self, coding: FaultCoding) -> Statusword {
        Statusword(match self {
            State::NotReadyToSwitchOn => 0x0000,
            State::SwitchOnDisabled => 0x0040,
            State::ReadyToSwitchOn => 0x0021,
            State::SwitchedOn => 0x0023,
            State::OperationEnabled => 0x0027,
            State::QuickStopActive => 0x0007,
            State::FaultReactionActive => 0x000F,
            State::Fault => match coding {
                FaultCoding::Dsp402 => 0x0008,
                FaultCoding::AsPrinted => 0x000F,
            },
        })
    }

    /// The state a statusword shows, decoded with the CiA 402 masks (004Fh for the states where
    /// bit 5 is "x", 006Fh otherwise). A TLC5xx printing Fault as 000Fh ([`FaultCoding::AsPrinted`])
    /// decodes as Fault reaction active; both mean "fault" to [`next_controlword`].
    pub const fn from_statusword(sw: Statusword) -> Result<State, StateError> {
        let v = sw.0;
        match (v & 0x004F, v & 0x006F) {
            (0x0000, _) => Ok(State::NotReadyToSwitchOn),
            (0x0040, _) => Ok(State::SwitchOnDisabled),
            (0x000F, _) => Ok(State::FaultReactionActive),
            (0x0008, _) => Ok(State::Fault),
            (_, 0x0021) => Ok(State::ReadyToSwitchOn),
            (_, 0x0023) => Ok(State::SwitchedOn),
            (_, 0x0027) => Ok(State::OperationEnabled),
            (_, 0x0007) => Ok(State::QuickStopActive),
            (_, bits) => Err(StateError::UndefinedPattern(v, bits)),
        }
    }

    /// The TLC5xx `driveStat` 2041h state code (bits 3..0), 2..9.
    pub const fn drive_stat_code(self) -> u16 {
        match self {
            State::NotReadyToSwitchOn => 2,
            State::SwitchOnDisabled => 3,
            State::ReadyToSwitchOn => 4,
            State::SwitchedOn => 5,
            State::OperationEnabled => 6,
            State::QuickStopActive => 7,
            State::FaultReactionActive => 8,
            State::Fault => 9,
        }
    }

    /// Whether the power section drives the motor (the operation mode may move the axis).
    pub const fn is_moving_allowed(self) -> bool {
        matches!(self, State::OperationEnabled)
    }
}

/// Master side: the controlword that moves a device showing `state` one step toward Operation
/// enabled, given the controlword sent last (for the fault reset edge and to keep the halt and
/// mode bits 4..6, 8..15). In a fault state it alternates bit 7 low and high, so a reset edge
/// reaches the device at the latest on the second step; from Quick stop active it sends Enable
/// operation (16), which resumes the interrupted command on a device that stays in quick stop.
pub const fn next_controlword(state: State, previous: Controlword) -> Controlword {
    let kept = Controlword(previous.0 & !Controlword::COMMAND_MASK);
    match state {
        State::FaultReactionActive | State::Fault => {
            if previous.fault_reset() {
                kept
            } else {
                Controlword(kept.0 | Controlword::FAULT_RESET)
            }
        }
        // Shutdown also serves Not ready to switch on: the MTR-DCI's 20 needs it, and the TLC5xx
        // moves on by itself (1) and then takes it (2).
        State::NotReadyToSwitchOn | State::SwitchOnDisabled => kept.with_command(Command::Shutdown),
        State::ReadyToSwitchOn
        | State::SwitchedOn
        | State::OperationEnabled
        | State::QuickStopActive => kept.with_command(Command::EnableOperation),
    }
}

/// The transitions one evaluation took (at most four: 1, 2, 3, 4 on a TLC5xx that is fed
/// Enable operation while still initialising is the longest chain).
pub type Transitions = Vec<Transition, 4>;

/// Device side: the state machine with its memory (state, last controlword for the fault reset
/// edge, the device's conditions). Each input settles the machine: it applies [`next`] until the
/// state stays, so one controlword can take 3 then 4 as the TLC5xx does.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceStateMachine {
    profile: DeviceProfile,
    state: State,
    last_cw: Controlword,
    conditions: Conditions,
}

impl DeviceStateMachine {
    /// A device at power-on: Not ready to switch on, controlword 0, self test not done.
    pub const fn new(profile: DeviceProfile) -> Self {
        DeviceStateMachine {
            profile,
            state: State::NotReadyToSwitchOn,
            last_cw: Controlword(0),
            conditions: Conditions {
                self_test_done: false,
                fault: false,
                fault_reaction_done: false,
                quick_stop_done: false,
                fault_reset_edge: false,
            },
        }
    }
    /// The device profile.
    pub const fn profile(&self) -> &DeviceProfile {
        &self.profile
    }
    /// The current state.
    pub const fn state(&self) -> State {
        self.state
    }
    /// The last controlword received.
    pub const fn controlword(&self) -> Controlword {
        self.last_cw
    }
    /// The current conditions (fault reset edge always false between evaluations).
    pub const fn conditions(&self) -> Conditions {
        self.conditions
    }
    /// The state bits of the statusword (no mode bits); see [`DeviceProfile::statusword`].
    pub const fn statusword(&self) -> Statusword {
        self.profile.statusword(self.state, Statusword(0))
    }

    /// A controlword arrived (RPDO or SDO write).
    pub fn handle_controlword(&mut self, cw: Controlword) -> Transitions {
        self.conditions.fault_reset_edge = cw.fault_reset() && !self.last_cw.fault_reset();
        self.last_cw = cw;
        self.settle()
    }
    /// The self test finished (or restarted, `false`).
    pub fn set_self_test_done(&mut self, done: bool) -> Transitions {
        self.conditions.self_test_done = done;
        self.settle()
    }
    /// A fault cause appeared (`true`, transition 13) or was removed (`false`, allowing 15).
    pub fn set_fault(&mut self, present: bool) -> Transitions {
        self.conditions.fault = present;
        if present {
            // A new reaction starts; its completion is reported afresh.
            self.conditions.fault_reaction_done = false;
        }
        self.settle()
    }
    /// The fault reaction finished (transition 14).
    pub fn set_fault_reaction_done(&mut self) -> Transitions {
        self.conditions.fault_reaction_done = true;
        self.settle()
    }
    /// The quick stop ramp reached standstill (`true`) or motion restarted (`false`).
    pub fn set_quick_stop_done(&mut self, done: bool) -> Transitions {
        self.conditions.quick_stop_done = done;
        self.settle()
    }

    fn settle(&mut self) -> Transitions {
        let mut taken = Transitions::new();
        for _ in 0..4 {
            let (to, tr) = next(self.state, self.last_cw, &self.conditions, &self.profile);
            // An edge is consumed by the first evaluation that sees it.
            self.conditions.fault_reset_edge = false;
            match tr {
                Some(t) => {
                    self.state = to;
                    // Cannot fail: at most four pushes into four slots.
                    let _ = taken.push(t);
                }
                None => break,
            }
        }
        taken
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cia402::{MTR_DCI, TLC5XX};

    const STATES: [State; 8] = [
        State::NotReadyToSwitchOn,
        State::SwitchOnDisabled,
        State::ReadyToSwitchOn,
        State::SwitchedOn,
        State::OperationEnabled,
        State::QuickStopActive,
        State::FaultReactionActive,
        State::Fault,
    ];

    fn ready(profile: DeviceProfile) -> DeviceStateMachine {
        let mut fsa = DeviceStateMachine::new(profile);
        fsa.set_self_test_done(true);
        fsa
    }

    #[test]
    fn tlc_state_switching_sequence_of_section_8_4() {
        // §5.2.3 trace: cw 0000, 0006, 0007, 000F → sw 0040, 0421, 0423, 0427 (bit 10 is the
        // profile position "target reached" of an axis at rest, added by the mode).
        let mut fsa = ready(TLC5XX);
        let rest = Statusword(Statusword::TARGET_REACHED);
        let steps = [
            (0x0000, 0x0040, State::SwitchOnDisabled),
            (0x0006, 0x0421, State::ReadyToSwitchOn),
            (0x0007, 0x0423, State::SwitchedOn),
            (0x000F, 0x0427, State::OperationEnabled),
        ];
        for (cw, sw, state) in steps {
            fsa.handle_controlword(Controlword::from_bytes((cw as u16).to_le_bytes()));
            assert_eq!(fsa.state(), state);
            assert_eq!(
                TLC5XX.statusword(fsa.state(), rest),
                Statusword(sw),
                "cw {cw:#06x}"
            );
        }
    }

    #[test]
    fn tlc_enable_operation_from_ready_runs_3_then_4() {
        // §5.4.3 trace: 0006h then 000Fh straight to Operation enable.
        let mut fsa = ready(TLC5XX);
        fsa.handle_controlword(Controlword(0x0006));
        assert_eq!(fsa.statusword(), Statusword(0x0021));
        let taken = fsa.handle_controlword(Controlword(0x000F));
        assert_eq!(taken.as_slice(), &[Transition::T3, Transition::T4]);
        assert_eq!(fsa.statusword(), Statusword(0x0027));
    }

    #[test]
    fn mtr_dci_uses_transitions_20_and_21() {
        let mut fsa = ready(MTR_DCI);
        assert_eq!(fsa.state(), State::NotReadyToSwitchOn);
        assert_eq!(
            fsa.handle_controlword(Controlword(0x0006)).as_slice(),
            &[Transition::T20]
        );
        assert_eq!(
            fsa.handle_controlword(Controlword(0x000F)).as_slice(),
            &[Transition::T21]
        );
        assert_eq!(fsa.state(), State::OperationEnabled);
    }

    #[test]
    fn quick_stop_stays_then_resumes_or_disables() {
        for profile in [TLC5XX, MTR_DCI] {
            let mut fsa = ready(profile);
            fsa.handle_controlword(Controlword(0x0006));
            fsa.handle_controlword(Controlword(0x000F));
            assert_eq!(
                fsa.handle_controlword(Controlword(0x0002)).as_slice(),
                &[Transition::T11]
            );
            assert_eq!(fsa.statusword().0 & Statusword::STATE_MASK, 0x0007);
            // No automatic exit from state 7, whatever the stop did.
            fsa.set_quick_stop_done(true);
            fsa.handle_controlword(Controlword(0x0006));
            assert_eq!(fsa.state(), State::QuickStopActive);
            assert_eq!(
                fsa.handle_controlword(Controlword(0x000F)).as_slice(),
                &[Transition::T16]
            );
            fsa.handle_controlword(Controlword(0x0002));
            assert_eq!(
                fsa.handle_controlword(Controlword(0x0000)).as_slice(),
                &[Transition::T12]
            );
            assert_eq!(fsa.state(), State::SwitchOnDisabled);
        }
    }

    #[test]
    fn quick_stop_option_1_to_4_leaves_when_the_stop_completes() {
        let profile = DeviceProfile {
            quick_stop: QuickStopOption::ToSwitchOnDisabled,
            ..TLC5XX
        };
        let mut fsa = ready(profile);
        fsa.handle_controlword(Controlword(0x0006));
        fsa.handle_controlword(Controlword(0x000F));
        fsa.handle_controlword(Controlword(0x0002));
        // Enable operation does not resume with this option.
        assert!(fsa.handle_controlword(Controlword(0x000F)).is_empty());
        assert_eq!(fsa.set_quick_stop_done(true).as_slice(), &[Transition::T12]);
        assert_eq!(fsa.state(), State::SwitchOnDisabled);
        assert_eq!(
            QuickStopOption::from_code(2),
            Some(QuickStopOption::ToSwitchOnDisabled)
        );
        assert_eq!(
            QuickStopOption::from_code(6),
            Some(QuickStopOption::StayInQuickStop)
        );
        assert_eq!(QuickStopOption::from_code(-1), None);
    }

    #[test]
    fn fault_reset_needs_a_rising_edge_and_the_cause_removed() {
        let mut fsa = ready(TLC5XX);
        fsa.handle_controlword(Controlword(0x0006));
        fsa.handle_controlword(Controlword(0x000F));
        assert_eq!(fsa.set_fault(true).as_slice(), &[Transition::T13]);
        assert_eq!(fsa.statusword(), Statusword(0x000F));
        assert_eq!(fsa.set_fault_reaction_done().as_slice(), &[Transition::T14]);
        assert_eq!(fsa.statusword(), Statusword(0x0008));
        // Edge while the cause persists: ignored.
        fsa.handle_controlword(Controlword(0x0080));
        assert_eq!(fsa.state(), State::Fault);
        fsa.set_fault(false);
        // Bit 7 held high is no edge.
        fsa.handle_controlword(Controlword(0x0080));
        assert_eq!(fsa.state(), State::Fault);
        fsa.handle_controlword(Controlword(0x0000));
        assert_eq!(
            fsa.handle_controlword(Controlword(0x0080)).as_slice(),
            &[Transition::T15]
        );
        assert_eq!(fsa.state(), State::SwitchOnDisabled);
        // "As printed" coding shows Fault as 000Fh.
        let printed = DeviceProfile {
            fault_coding: FaultCoding::AsPrinted,
            ..TLC5XX
        };
        assert_eq!(
            printed.statusword(State::Fault, Statusword(0)),
            Statusword(0x000F)
        );
    }

    #[test]
    fn mtr_dci_fault_reset_with_enable_goes_to_switched_on_then_enabled() {
        let mut fsa = ready(MTR_DCI);
        fsa.set_fault(true);
        fsa.set_fault_reaction_done();
        fsa.set_fault(false);
        let taken = fsa.handle_controlword(Controlword(0x008F));
        assert_eq!(taken.as_slice(), &[Transition::T19, Transition::T4]);
        assert_eq!(fsa.state(), State::OperationEnabled);
    }

    #[test]
    fn every_controlword_from_every_state_follows_the_table() {
        for profile in [TLC5XX, MTR_DCI] {
            for from in STATES {
                for cw in 0..=u16::MAX {
                    for bits in 0..32u8 {
                        let c = Conditions {
                            self_test_done: bits & 1 != 0,
                            fault: bits & 2 != 0,
                            fault_reaction_done: bits & 4 != 0,
                            quick_stop_done: bits & 8 != 0,
                            fault_reset_edge: bits & 16 != 0,
                        };
                        // Bits 8..11 (halt, reserved) meet one set of conditions only, to
                        // keep the run short; bits 0..7 and 12..15 meet all 32.
                        if cw & 0x0F00 != 0 && bits != 0b1_0101 {
                            continue;
                        }
                        let (to, tr) = next(from, Controlword(cw), &c, &profile);
                        match tr {
                            None => assert_eq!(to, from),
                            Some(t) => assert!(
                                allowed(from, to, t, profile.flavour),
                                "{from:?} --{cw:#06x}/{c:?}--> {to:?} by {t:?}"
                            ),
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn statusword_decoding_inverts_the_patterns() {
        for s in STATES {
            for extra in [0u16, 0x0410, 0xFF90, 0x1400] {
                let sw = Statusword(s.pattern(FaultCoding::Dsp402).0 | extra);
                assert_eq!(State::from_statusword(sw), Ok(s), "{sw:?}");
            }
        }
        assert_eq!(
            State::from_statusword(Statusword(0x0001)),
            Err(StateError::UndefinedPattern(0x0001, 0x0001))
        );
        assert_eq!(
            State::from_statusword(Statusword(0x0427)),
            Ok(State::OperationEnabled)
        );
    }

    #[test]
    fn next_controlword_reaches_operation_enabled_within_4_steps() {
        for profile in [TLC5XX, MTR_DCI] {
            for start in STATES {
                for previous in [Controlword(0), Controlword(0x0080), Controlword(0x0100)] {
                    let mut fsa = ready(profile);
                    force(&mut fsa, start);
                    fsa.last_cw = previous;
                    let mut cw = previous;
                    let mut steps = 0;
                    while fsa.state() != State::OperationEnabled {
                        assert!(
                            steps < 4,
                            "{start:?} from {previous:?}: stuck in {:?}",
                            fsa.state()
                        );
                        let seen = State::from_statusword(fsa.statusword()).unwrap_or(fsa.state());
                        cw = next_controlword(seen, cw);
                        fsa.handle_controlword(cw);
                        steps += 1;
                    }
                    // The halt bit the caller had set is kept.
                    assert_eq!(cw.halt(), previous.halt());
                }
            }
        }
    }

    /// Puts a ready device into `s` with no fault persisting.
    fn force(fsa: &mut DeviceStateMachine, s: State) {
        fsa.state = s;
        fsa.conditions.quick_stop_done = true;
        fsa.conditions.fault_reaction_done = true;
        // What the device does by itself from there (e.g. 14 once the reaction is done).
        fsa.settle();
    }
}
