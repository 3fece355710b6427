//! FHPP master side for the Festo MTR-DCI (seed 000 §5.5, §B.3), EMCA (seed 002 p.117–139,
//! p.172, p.180) and CMMO-ST (seed 001 §5.2–5.4, Fig. 6.3): one [`FhppAxis`] per drive, fed the
//! drive's 8 input bytes (TPDO1 / Modbus registers 4..7) once per cycle, producing the 8 output
//! bytes (RPDO1 / registers 0..3) with the codecs of `drivers::fhpp`.
//!
//! What each [`Demand`] puts on the wire (CCON always carries LOCK = 1 so FCT cannot take
//! control from under the coordinator; every demand that needs the drive enabled first runs
//! [`bring_up`] toward S4 in the demand's operating mode, except that a fault is never reset
//! by it: with SCON.FAULT the axis keeps CCON without edges and waits for `Acknowledge`):
//!
//! | demand | OPM | CCON / CPOS / bytes 3..8 | done when |
//! |---|---|---|---|
//! | `Disable` | kept | ENABLE = 0 | SCON.ENABLED = 0 |
//! | `Standstill` | kept | ENABLE, STOP; HALT = 1 (a running speed/force task is ended with HALT = 0 until MC) | S4 |
//! | `Acknowledge` | kept | fault: ENABLE = 0 and a RESET rising edge every second cycle (T9); else one RESET pulse (warnings) | SCON.FAULT = 0 |
//! | `Home` | record select | record 0, CPOS.HOM with the START/ACK/MC handshake | MC after ACK and SPOS.REF |
//! | `Jog` | kept | CPOS.JOGP / JOGN held (speed from PNU 530/531: the demand's speed is not sent) | ACK seen |
//! | `Follow` | direct | CDIR position absolute, a new target on each START rising edge, START held until ACK and released until ACK = 0 (a target every second cycle) | `motion_complete` |
//! | `Velocity` | direct | CDIR speed, value 2 = inc/s, value 1 = ramp %; START handshake on every new value (not MTR-DCI) | MC after ACK (speed reached) |
//! | `Force` | direct | CDIR force, value 2 = ‰ (EMCA/CMMO-ST) or % of rated current (MTR-DCI), value 1 = speed limit % | MC after ACK |
//! | `DriveRecord` | record select | byte 3 = record, START handshake | MC after ACK |
//! | `Teach` | kept | CPOS.TEACH high until SPOS.TEACH answers, then low until it answers again | the second answer |
//! | `Halt` | kept | CPOS.HALT = 0, the rest kept (a task demanded next first sends CPOS.CLEAR, TA6, so the halted task is deleted, not resumed) | SPOS.MOV = 0 |
//! | `QuickStop` | kept | CCON.STOP = 0 (T4) | SPOS.MOV = 0 and MC = 1 |
//!
//! Streaming (`Follow`): a START while a task runs retargets (MTR-DCI digest 000 E7; EMCA and
//! CMMO-ST with the direct start condition PNU 583 = 1 "interrupt", which the boot must write).
//! Each target is the path's position as many cycles ahead as the last handshake took (at
//! least [`MIN_LEAD_CYCLES`]: when the next target will arrive) plus the drive's braking
//! distance at the path's speed ([`FhppSettings::deceleration`]: the drive plans to stop at
//! every target), never going back while moving, and exact once the path stands; a speed of 5/4 of the path's (at least [`FhppSettings::min_follow_velocity`])
//! so the drive's generator keeps up. `motion_complete` is set only when the last target the
//! drive acknowledged equals the demanded position and SPOS.MC = 1 after that acknowledge.
//!
//! Feedback: the position from bytes 5..8 (record select, direct position and force mode); the
//! velocity from the position change per cycle (direct speed mode: bytes 5..8, signed like the
//! demand); the force from byte 4 in direct force mode. The fault number is not in the cyclic
//! image (it is PNU 205 / the EMCY): `fault_code` stays 0 here.

use drivers::fhpp::control::{Ccon, Cpos, DirectSetpoint, OutputImage, OutputPayload};
use drivers::fhpp::state::{BringUp, HandshakePhase, StartHandshake, bring_up};
use drivers::fhpp::status::{InputImage, InputPayload, Scon, Spos};
use drivers::fhpp::{ByteOrder, ControlMode, Opm, Variant};

use super::{AxisError, AxisState, Demand, Feedback, Image};
use crate::profile::fixed_point::div_i128;

/// Images without a position change after which the axis counts as standing (velocity 0).
const STILL_CYCLES: u32 = 8;

/// Bytes of the FHPP cyclic image, each way.
pub const IMAGE_LEN: usize = 8;

/// The fewest cycles a streamed target is placed ahead of the path (a target is taken every
/// second cycle at best); the lead follows the cycles the last handshake took.
pub const MIN_LEAD_CYCLES: u32 = 2;
/// The most cycles a streamed target is placed ahead of the path.
pub const MAX_LEAD_CYCLES: u32 = 8;

/// A START that the drive did not acknowledge within this many images is dropped and raised
/// again (the drive can miss an edge in the cycle it finishes the previous task).
const RETRY_CYCLES: u32 = 6;

/// Drive settings the axis needs to scale its setpoints (the boot reads or writes them).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FhppSettings {
    /// The speed byte 4's 100 % stands for in direct position mode and for the force-mode
    /// speed limit, inc/s: PNU 502 on the MTR-DCI, PNU 540 on the EMCA and CMMO-ST.
    pub base_velocity: u32,
    /// The lowest speed a streamed target is sent with, inc/s (the path's own speed is 0 at
    /// its ends).
    pub min_follow_velocity: u32,
    /// Direct speed mode ramp, % of PNU 560.
    pub speed_ramp_percent: u8,
    /// The drive's direct-mode deceleration, inc/s² (PNU 541/542, or 503 where those are 0).
    /// A streamed target is placed this much further ahead than the path's braking distance
    /// at it, so the drive's generator, which plans to stop at every target, runs at the path's
    /// speed instead of lagging by its own braking distance; 0 = no such allowance.
    pub deceleration: u32,
    /// Images a handshake phase may take before the demand is reported failed (0 = never).
    pub handshake_timeout: u32,
}

impl Default for FhppSettings {
    /// The simulators' default axis: 100 000 inc/s maximum speed, 480 000 inc/s².
    fn default() -> Self {
        FhppSettings {
            base_velocity: 100_000,
            min_follow_velocity: 5_000,
            speed_ramp_percent: 100,
            deceleration: 480_000,
            handshake_timeout: 0,
        }
    }
}

/// Where a `Follow` stream's START handshake stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Stream {
    /// START = 0 and ACK = 0 seen: a new target may be raised.
    Free,
    /// START = 1 with this target; waiting for ACK = 1.
    Raised { target: i32, images: u32 },
    /// ACK seen; START = 0, waiting for ACK = 0.
    Acknowledged,
    /// No ACK came: START = 0 for a cycle before raising again.
    Retry,
}

/// Where a demand that runs a sequence of its own stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Step {
    /// The drive is being brought to S4 (or the demand needs nothing more).
    Start,
    /// The START (or HOM) handshake runs.
    Handshake,
    /// Teach: TEACH = 1, waiting for the drive's answer (`images` since raised).
    TeachHigh { images: u32 },
    /// Teach: TEACH = 0, waiting for the second answer.
    TeachLow,
    /// Acknowledge of a warning: RESET = 1 sent once.
    ResetPulse,
    /// The demand is carried out.
    Done,
    /// The demand failed.
    Failed,
}

/// The master side of one FHPP drive.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FhppAxis {
    variant: Variant,
    order: ByteOrder,
    cycle_ns: u32,
    settings: FhppSettings,
    /// The drive's last image as received (its SCON.OPM checked). The parts a cycle reads are
    /// decoded where they are read: a cycle decodes only the bits it looks at.
    status: Option<[u8; IMAGE_LEN]>,
    feedback: Feedback,
    /// What was sent last.
    ccon: Ccon,
    cpos: Cpos,
    payload: OutputPayload,
    demand: Demand,
    step: Step,
    handshake: StartHandshake,
    stream: Stream,
    /// The target the drive acknowledged last in the stream.
    acked_target: Option<i32>,
    /// A speed or force task runs (they go on after MC until halted or replaced).
    continuous: bool,
    /// The record select payload's record number (kept for teach and halt).
    record: u8,
    /// Cycles since the last streamed START was raised.
    since_raise: u32,
    /// CPOS.CLEAR images still to send before a task after a halt.
    clearing: u8,
    /// Cycles since the last image arrived.
    gap: u32,
    /// The position at its last change, and the images since (the velocity estimate).
    changed_at: i64,
    since_change: u32,
}

impl FhppAxis {
    /// The master side of a `variant` drive exchanged every `cycle_ns`, with the default
    /// [`FhppSettings`] and the variant's usual byte order.
    pub fn new(variant: Variant, cycle_ns: u32) -> FhppAxis {
        FhppAxis {
            variant,
            order: variant.default_byte_order(),
            cycle_ns: cycle_ns.max(1),
            settings: FhppSettings::default(),
            status: None,
            feedback: Feedback::default(),
            ccon: Ccon::from_byte(0),
            cpos: Cpos::idle(),
            payload: OutputPayload::Record { record: 0 },
            demand: Demand::Disable,
            step: Step::Start,
            handshake: StartHandshake::new(0),
            stream: Stream::Free,
            acked_target: None,
            continuous: false,
            record: 0,
            since_raise: 0,
            clearing: 0,
            gap: 0,
            changed_at: 0,
            since_change: 0,
        }
    }

    /// Replaces the settings (the boot learns them from the drive).
    pub fn set_settings(&mut self, settings: FhppSettings) {
        *self = self.clone().with_settings(settings);
    }

    /// The same axis with other drive settings.
    pub fn with_settings(mut self, settings: FhppSettings) -> FhppAxis {
        self.settings = settings;
        self.handshake = StartHandshake::new(settings.handshake_timeout);
        self
    }

    /// The same axis with another byte order (FHPP over a bus other than the variant's usual).
    pub fn with_byte_order(mut self, order: ByteOrder) -> FhppAxis {
        self.order = order;
        self
    }

    /// The device variant.
    pub fn variant(&self) -> Variant {
        self.variant
    }

    /// The settings.
    pub fn settings(&self) -> &FhppSettings {
        &self.settings
    }

    /// What the drive reported last, as the last exchange returned it (kept when an image
    /// could not be decoded).
    pub fn feedback(&self) -> &Feedback {
        &self.feedback
    }

    /// Forgets the drive's state: offline until the next image, the demand starts anew.
    pub fn reset(&mut self) {
        *self = FhppAxis::new(self.variant, self.cycle_ns)
            .with_settings(self.settings)
            .with_byte_order(self.order);
    }

    /// One cycle (see [`super::DriveAxis::exchange`]).
    pub fn exchange(
        &mut self,
        input: Option<&[u8]>,
        demand: &Demand,
        out: &mut Image,
    ) -> Result<&Feedback, AxisError> {
        // Cycles since the last image, for the velocity estimate.
        self.gap = self.gap.saturating_add(1);
        let fresh = match input {
            Some(bytes) => match self.take_input(bytes) {
                Ok(()) => true,
                Err(e) => {
                    self.write_safe(out);
                    return Err(e);
                }
            },
            None => false,
        };
        if !same_task(&self.demand, demand) {
            self.begin(demand);
        }
        self.demand = *demand;
        if let Err(e) = self.check(demand) {
            self.step = Step::Failed;
            self.write_safe(out);
            self.feedback.failed = true;
            self.feedback.done = false;
            return Err(e);
        }
        self.run(fresh);
        let image = OutputImage {
            ccon: self.ccon,
            cpos: self.cpos,
            payload: self.payload,
        };
        *out = image_of(image.to_bytes(self.order));
        self.update_feedback();
        Ok(&self.feedback)
    }

    /// Checks the drive's image, keeps it in `status` and takes the position, velocity and
    /// force feedback from it.
    fn take_input(&mut self, bytes: &[u8]) -> Result<(), AxisError> {
        let b: [u8; IMAGE_LEN] = *bytes.first_chunk::<IMAGE_LEN>().ok_or(AxisError::Short {
            len: bytes.len(),
            need: IMAGE_LEN,
        })?;
        let img = InputImage::from_bytes(&b, self.variant, self.order)
            .map_err(|_| AxisError::Decode("FHPP SCON.OPM holds a reserved mode"))?;
        let had = self.status.is_some();
        let mut position = self.feedback.position;
        let mut velocity = None;
        let mut force = 0;
        match img.payload {
            InputPayload::Record { position: p, .. } => position = i64::from(p),
            InputPayload::Direct {
                sdir,
                value1,
                value2,
            } => match sdir.com {
                ControlMode::Position => position = i64::from(value2),
                ControlMode::Force => {
                    position = i64::from(value2);
                    force = i32::from(value1) * 10;
                }
                ControlMode::Speed => {
                    let sign = match self.demand {
                        Demand::Velocity { velocity } if velocity < 0 => -1,
                        _ => 1,
                    };
                    velocity = Some(sign * i64::from(value2));
                }
                ControlMode::Reserved => {}
            },
        }
        // The drive refreshes its actual position at its own internal cycle (1, 5 or 2 ms), not
        // at ours: a velocity from one image to the next would alternate between 0 and a
        // multiple of the real one. Estimate it from position change to position change, over
        // the time between them; still for `STILL_CYCLES` images means standing.
        self.since_change = self.since_change.saturating_add(self.gap.max(1));
        self.feedback.velocity = match velocity {
            Some(v) => v,
            None if !had => {
                self.changed_at = position;
                self.since_change = 0;
                0
            }
            None if position != self.changed_at => {
                let span =
                    i64::from(self.cycle_ns).saturating_mul(i64::from(self.since_change.max(1)));
                let v = (position - self.changed_at) * 1_000_000_000 / span;
                self.changed_at = position;
                self.since_change = 0;
                v
            }
            None if self.since_change >= STILL_CYCLES => 0,
            None => self.feedback.velocity,
        };
        self.feedback.position = position;
        self.feedback.force = force;
        self.status = Some(b);
        self.gap = 0;
        Ok(())
    }

    /// A new demand: its sequence starts from the beginning.
    fn begin(&mut self, demand: &Demand) {
        self.step = Step::Start;
        self.handshake = StartHandshake::new(self.settings.handshake_timeout);
        self.feedback.failed = false;
        self.feedback.done = false;
        // `begin` runs only when the task changes: a new stream starts afresh.
        self.stream = Stream::Free;
        self.acked_target = None;
        self.since_raise = 0;
        // After a halt the drive sits in "intermediate stop" keeping its task: a START there
        // resumes that task (TA4) and HOM is ignored, so a new task first deletes it (TA6).
        let task = matches!(
            demand,
            Demand::Follow { .. }
                | Demand::Home
                | Demand::DriveRecord { .. }
                | Demand::Velocity { .. }
                | Demand::Force { .. }
        );
        self.clearing = if task && self.demand == Demand::Halt {
            2
        } else {
            0
        };
    }

    /// Sends CPOS.CLEAR (HALT = 1, no START) until the drive has had an image with it; `true`
    /// while that runs.
    fn clear_halted(&mut self, fresh: bool) -> bool {
        if fresh {
            self.clearing = self.clearing.saturating_sub(1);
        }
        if self.clearing == 0 {
            return false;
        }
        self.enable(self.current_opm());
        self.cpos = Cpos {
            clear: true,
            ..Cpos::idle()
        };
        true
    }

    /// Refuses what the variant cannot do.
    fn check(&self, demand: &Demand) -> Result<(), AxisError> {
        match demand {
            Demand::Velocity { .. } if !self.variant.has_speed_mode() => {
                Err(AxisError::Unsupported("direct speed mode on an MTR-DCI"))
            }
            Demand::DriveRecord { number } if *number == 0 => {
                Err(AxisError::Unsupported("record 0 (homing: use Home)"))
            }
            Demand::DriveRecord { number } if *number > self.variant.max_record() => Err(
                AxisError::Unsupported("a record number above the drive's table"),
            ),
            _ => Ok(()),
        }
    }

    /// The safe image: the last CCON, HALT = 0 (stop on the ramp, keep the task), no edges.
    fn write_safe(&mut self, out: &mut Image) {
        self.cpos = Cpos {
            halt: false,
            ..Cpos::idle()
        };
        let image = OutputImage {
            ccon: Ccon {
                reset: false,
                ..self.ccon
            },
            cpos: self.cpos,
            payload: self.payload,
        };
        *out = image_of(image.to_bytes(self.order));
    }

    fn scon_spos(&self) -> Option<(Scon, Spos)> {
        self.status
            .map(|b| (Scon::from_byte(b[0]), Spos::from_byte(b[1])))
    }

    /// The operating mode the current payload asks for.
    fn current_opm(&self) -> Opm {
        match self.payload {
            OutputPayload::Record { .. } => Opm::RecordSelect,
            OutputPayload::Direct(_) => Opm::Direct,
        }
    }

    /// Brings the drive toward S4 in `opm`; `true` once there. Sets CCON and an idle CPOS
    /// while on the way.
    fn enable(&mut self, opm: Opm) -> bool {
        let Some((scon, _)) = self.scon_spos() else {
            // Nothing heard yet: stay passive.
            self.ccon = Ccon {
                lock: true,
                opm,
                ..Ccon::from_byte(0)
            };
            self.cpos = Cpos::idle();
            return false;
        };
        if scon.fault {
            // Only `Acknowledge` resets a fault: an enabling demand waits without an edge
            // (CCON kept, RESET = 0; on the MTR-DCI an ENABLE fall would acknowledge, T9).
            self.ccon.reset = false;
            self.cpos = Cpos::idle();
            return false;
        }
        match bring_up(scon, self.ccon, opm) {
            BringUp::Ready(c) => {
                self.ccon = c;
                true
            }
            BringUp::Send(c) => {
                self.ccon = c;
                self.cpos = Cpos::idle();
                false
            }
            BringUp::Blocked(_) => {
                self.ccon = Ccon {
                    enable: true,
                    stop: true,
                    lock: true,
                    opm,
                    ..Ccon::from_byte(0)
                };
                self.cpos = Cpos::idle();
                false
            }
        }
    }

    fn record_payload(&mut self, record: u8) {
        self.record = record;
        self.payload = OutputPayload::Record { record };
    }

    /// The demand's outputs for this cycle; `fresh` if a new image arrived.
    fn run(&mut self, fresh: bool) {
        let status = self.scon_spos();
        match self.demand {
            Demand::Disable => {
                self.ccon = Ccon {
                    lock: true,
                    opm: self.current_opm(),
                    ..Ccon::from_byte(0)
                };
                self.cpos = Cpos::idle();
                self.continuous = false;
                if status.is_some_and(|(scon, _)| !scon.enabled) {
                    self.step = Step::Done;
                }
            }
            Demand::Standstill => {
                let ready = self.enable(self.current_opm());
                if ready {
                    self.cpos = Cpos::idle();
                    if self.continuous {
                        // Speed and force control go on after MC: HALT ends them.
                        self.cpos.halt = false;
                        if fresh && status.is_some_and(|(_, spos)| spos.mc && !spos.mov) {
                            self.continuous = false;
                        }
                    }
                    if !self.continuous {
                        self.step = Step::Done;
                    }
                }
            }
            Demand::Acknowledge => self.acknowledge(fresh),
            Demand::Home => {
                self.record_payload(0);
                self.handshake_task(fresh, Opm::RecordSelect, true);
                if self.step == Step::Done && !status.is_some_and(|(_, s)| s.referenced) {
                    self.step = Step::Failed;
                }
            }
            Demand::Jog { positive, .. } => {
                if self.enable(self.current_opm()) {
                    self.cpos = Cpos {
                        jogp: positive,
                        jogn: !positive,
                        ..Cpos::idle()
                    };
                    if fresh && status.is_some_and(|(_, s)| s.ack) {
                        self.step = Step::Done;
                    }
                }
            }
            Demand::Follow { position, velocity } => self.follow(fresh, position, velocity),
            Demand::Velocity { velocity } => {
                let v = clamp_i32(velocity);
                self.payload = OutputPayload::Direct(DirectSetpoint::speed(
                    v,
                    self.settings.speed_ramp_percent.max(1),
                    false,
                ));
                self.handshake_task(fresh, Opm::Direct, false);
                self.continuous = true;
            }
            Demand::Force {
                permille,
                velocity_limit,
            } => {
                let value = match self.variant {
                    // MTR-DCI: % of the rated current (PNU 1035).
                    Variant::MtrDci => permille / 10,
                    Variant::Emca | Variant::CmmoSt => permille,
                };
                let limit = self.speed_percent(velocity_limit.unsigned_abs());
                self.payload = OutputPayload::Direct(DirectSetpoint::force(value, limit, false));
                self.handshake_task(fresh, Opm::Direct, false);
                self.continuous = true;
            }
            Demand::DriveRecord { number } => {
                self.record_payload(number);
                self.handshake_task(fresh, Opm::RecordSelect, false);
            }
            Demand::Teach => self.teach(fresh),
            Demand::Halt => {
                // Keep CCON as it is (a disabled drive stays disabled), drop the edges.
                self.ccon.reset = false;
                self.cpos = Cpos {
                    halt: false,
                    ..Cpos::idle()
                };
                if fresh && status.is_some_and(|(_, s)| !s.mov) {
                    self.step = Step::Done;
                }
            }
            Demand::QuickStop => {
                self.ccon = Ccon {
                    enable: true,
                    stop: false,
                    brake: false,
                    reset: false,
                    lock: true,
                    opm: self.current_opm(),
                };
                self.cpos = Cpos::idle();
                self.continuous = false;
                // In S3 the drive shows MC = 1 once it stands.
                if fresh && status.is_some_and(|(_, s)| !s.mov && s.mc) {
                    self.step = Step::Done;
                }
            }
        }
    }

    /// A task started with the START (or HOM, `hom`) handshake in `opm`: enable, then the
    /// four steps; done at MC after ACK.
    fn handshake_task(&mut self, fresh: bool, opm: Opm, hom: bool) {
        if self.clear_halted(fresh) || !self.enable(opm) {
            return;
        }
        if self.step == Step::Start {
            self.handshake.request();
            self.step = Step::Handshake;
        }
        if self.step == Step::Handshake
            && fresh
            && let Some((scon, spos)) = self.scon_spos()
        {
            match self.handshake.poll(scon, spos) {
                HandshakePhase::Complete => self.step = Step::Done,
                HandshakePhase::Failed | HandshakePhase::TimedOut => self.step = Step::Failed,
                _ => {}
            }
        }
        let bit = self.step == Step::Handshake && self.handshake.start_bit();
        self.cpos = Cpos {
            start: bit && !hom,
            hom: bit && hom,
            ..Cpos::idle()
        };
    }

    /// `Acknowledge`: RESET edges with ENABLE = 0 while SCON.FAULT; a single pulse otherwise.
    fn acknowledge(&mut self, fresh: bool) {
        let Some((scon, _)) = self.scon_spos() else {
            return;
        };
        self.cpos = Cpos::idle();
        if scon.fault {
            self.ccon = Ccon {
                enable: false,
                stop: false,
                brake: false,
                reset: !self.ccon.reset,
                lock: true,
                opm: self.current_opm(),
            };
            // `Handshake` here: RESET edges are being sent.
            self.step = Step::Handshake;
            return;
        }
        match self.step {
            // The fault went with one of the edges.
            Step::Handshake if fresh => {
                self.ccon.reset = false;
                self.step = Step::Done;
            }
            // No fault: one RESET pulse acknowledges the warnings.
            Step::Start if fresh => {
                self.ccon.reset = true;
                self.step = Step::ResetPulse;
            }
            Step::ResetPulse => {
                self.ccon.reset = false;
                self.step = Step::Done;
            }
            _ => self.ccon.reset = false,
        }
    }

    /// `Teach`: TEACH high until the drive answers (EMCA/CMMO-ST: SPOS.TEACH = 1; MTR-DCI:
    /// SPOS.TEACH = 0), then low until the second answer (SPOS.TEACH = 0 / 1: value taken).
    fn teach(&mut self, fresh: bool) {
        if !self.enable(self.current_opm()) {
            return;
        }
        let mtr = self.variant == Variant::MtrDci;
        let spos_teach = self.scon_spos().map(|(_, s)| s.teach).unwrap_or(false);
        if self.step == Step::Start {
            self.step = Step::TeachHigh { images: 0 };
        }
        match self.step {
            Step::TeachHigh { images } if fresh => {
                let images = images + 1;
                // At least two images with TEACH high: the drive has sampled it.
                if images >= 2 && spos_teach != mtr {
                    self.step = Step::TeachLow;
                } else {
                    self.step = Step::TeachHigh { images };
                }
            }
            Step::TeachLow if fresh && spos_teach == mtr => self.step = Step::Done,
            _ => {}
        }
        self.cpos = Cpos {
            teach: matches!(self.step, Step::TeachHigh { .. }),
            ..Cpos::idle()
        };
    }

    /// `Follow`: direct position targets on START edges, one per handshake.
    fn follow(&mut self, fresh: bool, position: i64, velocity: i64) {
        self.since_raise = self.since_raise.saturating_add(1);
        let lead = self.since_raise.clamp(MIN_LEAD_CYCLES, MAX_LEAD_CYCLES);
        let v = i128::from(velocity);
        let mut ahead = div_i128(
            v * i128::from(lead) * i128::from(self.cycle_ns),
            1_000_000_000,
        );
        if self.settings.deceleration > 0 {
            // The drive's braking distance at the path's speed, in the direction of travel.
            ahead += div_i128(v * v.abs(), 2 * i128::from(self.settings.deceleration));
        }
        let mut target = clamp_i32(
            (i128::from(position) + ahead).clamp(i128::from(i32::MIN), i128::from(i32::MAX)) as i64,
        );
        // While moving, a target never goes back against the direction of travel (the
        // allowance shrinks when the path brakes harder than the drive); at rest it is exact.
        if let Some(last) = self.acked_target
            && ((velocity > 0 && target < last) || (velocity < 0 && target > last))
        {
            target = last;
        }
        let speed = self.follow_speed(velocity);
        if self.clear_halted(fresh) {
            return;
        }
        if !self.enable(Opm::Direct) {
            self.stream = Stream::Free;
            self.payload = OutputPayload::Direct(DirectSetpoint::position(target, speed, false));
            return;
        }
        if fresh && let Some((_, spos)) = self.scon_spos() {
            self.stream = match self.stream {
                Stream::Raised { target, .. } if spos.ack => {
                    self.acked_target = Some(target);
                    Stream::Acknowledged
                }
                Stream::Raised { images, .. } if images + 1 >= RETRY_CYCLES => Stream::Retry,
                Stream::Raised { target, images } => Stream::Raised {
                    target,
                    images: images + 1,
                },
                Stream::Acknowledged if !spos.ack => Stream::Free,
                Stream::Retry if !spos.ack => Stream::Free,
                s => s,
            };
        }
        if self.stream == Stream::Free && self.acked_target != Some(target) {
            self.stream = Stream::Raised { target, images: 0 };
            self.since_raise = 0;
            self.payload = OutputPayload::Direct(DirectSetpoint::position(target, speed, false));
        }
        self.cpos = Cpos {
            start: matches!(self.stream, Stream::Raised { .. }),
            ..Cpos::idle()
        };
        let arrived = self.stream == Stream::Free
            && self.acked_target == Some(clamp_i32(position))
            && self.scon_spos().is_some_and(|(_, s)| s.mc);
        self.step = if arrived { Step::Done } else { Step::Start };
    }

    /// Byte 4 for a streamed target: 5/4 of the path's speed, at least the minimum, in % of
    /// the base speed (1..=100).
    fn follow_speed(&self, velocity: i64) -> u8 {
        let v = velocity.unsigned_abs().saturating_mul(5) / 4;
        let v = v.max(u64::from(self.settings.min_follow_velocity));
        self.speed_percent(v)
    }

    /// `v` inc/s as a percentage of the base speed, rounded up, 1..=100.
    fn speed_percent(&self, v: u64) -> u8 {
        let base = u64::from(self.settings.base_velocity.max(1));
        (v.saturating_mul(100).div_ceil(base)).clamp(1, 100) as u8
    }

    fn update_feedback(&mut self) {
        let f = &mut self.feedback;
        f.done = self.step == Step::Done;
        f.failed = self.step == Step::Failed;
        let Some(b) = self.status else {
            f.state = AxisState::Offline;
            return;
        };
        let (scon, spos) = (Scon::from_byte(b[0]), Spos::from_byte(b[1]));
        f.homed = spos.referenced;
        f.warning = scon.warn;
        // SCON and SPOS as received (every bit of both is a flag or the checked OPM).
        f.status = u16::from_le_bytes([b[0], b[1]]);
        f.motion_complete = match self.demand {
            Demand::Follow { .. } => f.done,
            Demand::Home | Demand::DriveRecord { .. } | Demand::Velocity { .. } => f.done,
            Demand::Force { .. } => f.done,
            _ => spos.mc,
        };
        let wants_power = !matches!(self.demand, Demand::Disable | Demand::Acknowledge);
        f.state = if scon.fault {
            AxisState::Fault
        } else if !scon.enabled {
            if wants_power {
                AxisState::Enabling
            } else {
                AxisState::Disabled
            }
        } else if !scon.open {
            match self.demand {
                Demand::QuickStop => AxisState::Stopping,
                Demand::Disable => AxisState::Disabled,
                _ => AxisState::Enabling,
            }
        } else if (!spos.halt && !spos.mc)
            || (matches!(self.demand, Demand::Halt | Demand::QuickStop) && spos.mov)
        {
            AxisState::Stopping
        } else if spos.mc && !spos.mov {
            AxisState::Ready
        } else if matches!(self.demand, Demand::Home) {
            AxisState::Homing
        } else {
            AxisState::Moving
        };
    }
}

/// Whether `new` continues the task of `old` (so its handshake goes on) rather than starting
/// a new one: the same kind of demand with the same record, direction, velocity or force.
/// `Follow` setpoints change every cycle and stay one stream.
fn same_task(old: &Demand, new: &Demand) -> bool {
    match (old, new) {
        (Demand::Follow { .. }, Demand::Follow { .. }) => true,
        (Demand::Jog { positive: a, .. }, Demand::Jog { positive: b, .. }) => a == b,
        _ => old == new,
    }
}

fn clamp_i32(v: i64) -> i32 {
    v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

fn image_of(bytes: [u8; 8]) -> Image {
    Image {
        data: bytes,
        len: IMAGE_LEN as u8,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CYCLE: u32 = 2_000_000;

    fn axis(v: Variant) -> FhppAxis {
        FhppAxis::new(v, CYCLE)
    }

    /// An input image in little-endian: SCON, SPOS, byte 3, byte 4, value.
    fn inp(scon: u8, spos: u8, b3: u8, b4: u8, value: i32) -> [u8; 8] {
        let v = value.to_le_bytes();
        [scon, spos, b3, b4, v[0], v[1], v[2], v[3]]
    }

    fn ex(a: &mut FhppAxis, input: Option<&[u8]>, d: Demand) -> ([u8; 8], Feedback) {
        let mut out = Image::default();
        let fb = a.exchange(input, &d, &mut out).unwrap();
        assert_eq!(out.len, 8);
        (out.data, *fb)
    }

    #[test]
    fn velocity_is_estimated_between_the_drives_position_updates() {
        // The drive refreshes its position every 5 ms (an EMCA), the coordinator exchanges
        // every 2 ms: at 100 000 inc/s the position steps by 500 inc at 0, 5, 10 ms...
        let mut a = axis(Variant::Emca);
        let mut seen = std::vec::Vec::new();
        for k in 0..40u32 {
            let t_ms = 2 * k;
            let pos = (t_ms / 5 * 5 * 100) as i32;
            let (_, fb) = ex(
                &mut a,
                Some(&inp(0x13, 0x04, 0, 0, pos)),
                Demand::Standstill,
            );
            if k >= 5 {
                seen.push(fb.velocity);
            }
        }
        // Never the 0 / 2.5x alternation of a per-image difference.
        for v in &seen {
            assert!((60_000..=140_000).contains(v), "{seen:?}");
        }
        // Standing: after STILL_CYCLES images without a change the velocity is 0.
        let mut last = 0;
        for _ in 0..=STILL_CYCLES {
            last = ex(
                &mut a,
                Some(&inp(0x13, 0x04, 0, 0, 7_800)),
                Demand::Standstill,
            )
            .1
            .velocity;
        }
        assert_eq!(last, 0);
    }

    #[test]
    fn bring_up_sends_enable_stop_lock_then_reports_ready() {
        let mut a = axis(Variant::MtrDci);
        // Power-on image: drive blocked, VLOAD, MC.
        let (out, fb) = ex(&mut a, Some(&inp(0x10, 0x04, 0, 0, 0)), Demand::Standstill);
        // CCON = ENABLE | STOP | LOCK (0x23), CPOS = HALT.
        assert_eq!(&out[..3], &[0x23, 0x01, 0x00]);
        assert_eq!(fb.state, AxisState::Enabling);
        assert!(!fb.done);
        let (out, fb) = ex(
            &mut a,
            Some(&inp(0x13, 0x05, 0, 0, 1234)),
            Demand::Standstill,
        );
        assert_eq!(&out[..2], &[0x23, 0x01]);
        assert_eq!(fb.state, AxisState::Ready);
        assert!(fb.done);
        assert_eq!(fb.position, 1234);
    }

    #[test]
    fn the_status_word_is_scon_and_spos_as_received_and_a_reserved_mode_keeps_the_last() {
        let mut a = axis(Variant::MtrDci);
        // Every SCON flag and the direct mode; SPOS with MC, MOV, DEV and REF.
        let (_, fb) = ex(&mut a, Some(&inp(0x7F, 0xB4, 0, 0, 0)), Demand::Standstill);
        assert_eq!(fb.status, 0xB47F);
        assert!(fb.warning && fb.homed);
        assert_eq!(fb.state, AxisState::Fault);
        let (_, fb) = ex(&mut a, Some(&inp(0x13, 0x05, 0, 0, 7)), Demand::Standstill);
        assert_eq!(fb.status, 0x0513);
        assert_eq!(fb.position, 7);
        // OPM 3 is reserved: refused, and the image before it stays the drive's last.
        let mut out = Image::default();
        let e = a.exchange(
            Some(&inp(0xD3, 0x00, 0, 0, 9)),
            &Demand::Standstill,
            &mut out,
        );
        assert!(matches!(e, Err(AxisError::Decode(_))));
        assert_eq!(a.feedback.status, 0x0513);
        assert_eq!(a.feedback.position, 7);
    }

    #[test]
    fn no_image_yet_is_offline_and_passive() {
        let mut a = axis(Variant::Emca);
        let (out, fb) = ex(&mut a, None, Demand::Standstill);
        assert_eq!(out[0] & 0x03, 0, "no ENABLE before the drive was heard");
        assert_eq!(fb.state, AxisState::Offline);
    }

    #[test]
    fn short_image_is_an_error_with_a_halting_image() {
        let mut a = axis(Variant::MtrDci);
        ex(&mut a, Some(&inp(0x13, 0x05, 0, 0, 0)), Demand::Standstill);
        let mut out = Image::default();
        let e = a.exchange(Some(&[0x13, 0x05]), &Demand::Standstill, &mut out);
        assert_eq!(e, Err(AxisError::Short { len: 2, need: 8 }));
        assert_eq!(out.data[1] & 0x01, 0, "CPOS.HALT = 0");
    }

    #[test]
    fn homing_runs_the_hom_handshake_in_record_select() {
        let mut a = axis(Variant::MtrDci);
        let ready = inp(0x13, 0x05, 0, 0, 0);
        let (out, _) = ex(&mut a, Some(&ready), Demand::Home);
        // Record select, HOM raised at once (ACK = 0).
        assert_eq!(&out[..3], &[0x23, 0x05, 0x00]);
        // ACK = 1, MC = 0: HOM drops.
        let (out, fb) = ex(&mut a, Some(&inp(0x13, 0x03, 0, 0, 0)), Demand::Home);
        assert_eq!(out[1], 0x01);
        assert_eq!(fb.state, AxisState::Homing);
        // ACK = 0, still running; then MC with REF: done.
        let (_, fb) = ex(&mut a, Some(&inp(0x13, 0x11, 0, 0, 0)), Demand::Home);
        assert!(!fb.done);
        let (out, fb) = ex(&mut a, Some(&inp(0x13, 0x85, 0, 0, 0)), Demand::Home);
        assert_eq!(out[1], 0x01);
        assert!(fb.done && fb.homed && fb.motion_complete);
    }

    #[test]
    fn record_select_start_ack_mc_and_stale_mc_is_not_completion() {
        let mut a = axis(Variant::Emca);
        let d = Demand::DriveRecord { number: 7 };
        let (out, _) = ex(&mut a, Some(&inp(0x13, 0x85, 0, 0, 0)), d);
        assert_eq!(&out[..3], &[0x23, 0x03, 7], "START with record 7");
        // The old MC is still up, ACK not yet: not done, START held.
        let (out, fb) = ex(&mut a, Some(&inp(0x13, 0x85, 0, 0, 0)), d);
        assert_eq!(out[1], 0x03);
        assert!(!fb.done);
        let (out, _) = ex(&mut a, Some(&inp(0x13, 0x93, 0, 0, 0)), d);
        assert_eq!(out[1], 0x01, "START released after ACK");
        let (_, fb) = ex(&mut a, Some(&inp(0x13, 0x91, 0, 0, 0)), d);
        assert!(!fb.done);
        let (_, fb) = ex(&mut a, Some(&inp(0x13, 0x85, 7, 0, 5000)), d);
        assert!(fb.done && fb.motion_complete);
        assert_eq!(fb.position, 5000);
    }

    #[test]
    fn follow_raises_start_every_second_image_with_the_lead_target() {
        let mut a = axis(Variant::MtrDci);
        // Direct mode ready (SCON OPM bits = 01 -> 0x53), referenced, MC.
        let ready = |spos| inp(0x53, spos, 0, 0, 0);
        let d = |p| Demand::Follow {
            position: p,
            velocity: 10_000,
        };
        let (out, _) = ex(&mut a, Some(&ready(0x85)), d(0));
        // CCON direct (0x63), START, CDIR absolute position, 13 % (12 500 inc/s of 100 000),
        // target 0 + 10 000 inc/s * 4 ms = 40, plus the drive's braking distance at 10 000 inc/s
        // (10 000² / (2 * 480 000) = 104).
        assert_eq!(&out[..4], &[0x63, 0x03, 0x00, 13]);
        assert_eq!(i32::from_le_bytes([out[4], out[5], out[6], out[7]]), 144);
        let (out, _) = ex(&mut a, Some(&ready(0x83)), d(20));
        assert_eq!(out[1], 0x01, "ACK seen: START = 0");
        let (out, fb) = ex(&mut a, Some(&ready(0x81)), d(40));
        assert_eq!(out[1], 0x03, "ACK = 0: the next target at once");
        assert_eq!(i32::from_le_bytes([out[4], out[5], out[6], out[7]]), 184);
        assert!(!fb.motion_complete);
    }

    #[test]
    fn follow_completes_only_on_the_last_target_with_mc() {
        let mut a = axis(Variant::CmmoSt);
        let be = |scon: u8, spos: u8| {
            let mut b = [scon, spos, 0, 0, 0, 0, 0, 0];
            b[4..].copy_from_slice(&500i32.to_be_bytes());
            b
        };
        let d = Demand::Follow {
            position: 500,
            velocity: 0,
        };
        let (out, _) = ex(&mut a, Some(&be(0x53, 0x85)), d);
        assert_eq!(out[1], 0x03);
        // Big-endian target on the CMMO-ST.
        assert_eq!(&out[4..], &500i32.to_be_bytes());
        // MC is still the old task's: not complete.
        let (_, fb) = ex(&mut a, Some(&be(0x53, 0x85)), d);
        assert!(!fb.motion_complete);
        ex(&mut a, Some(&be(0x53, 0x93)), d);
        let (out, fb) = ex(&mut a, Some(&be(0x53, 0x91)), d);
        assert_eq!(out[1], 0x01, "no new START: the target is unchanged");
        assert!(!fb.motion_complete);
        let (_, fb) = ex(&mut a, Some(&be(0x53, 0x85)), d);
        assert!(fb.motion_complete && fb.done);
    }

    #[test]
    fn acknowledge_makes_reset_edges_with_enable_low() {
        let mut a = axis(Variant::Emca);
        let fault = inp(0x18, 0x04, 0, 0, 0);
        let (o1, fb) = ex(&mut a, Some(&fault), Demand::Acknowledge);
        assert_eq!(fb.state, AxisState::Fault);
        let (o2, _) = ex(&mut a, Some(&fault), Demand::Acknowledge);
        // ENABLE = 0, RESET alternates: one of two consecutive images has the rising edge.
        assert_eq!(o1[0] & 0x01, 0);
        assert_ne!(o1[0] & 0x08, o2[0] & 0x08);
        let (o3, fb) = ex(&mut a, Some(&inp(0x10, 0x04, 0, 0, 0)), Demand::Acknowledge);
        assert_eq!(o3[0] & 0x08, 0);
        assert!(fb.done);
        assert_eq!(fb.state, AxisState::Disabled);
    }

    #[test]
    fn enabling_never_resets_a_fault() {
        let mut a = axis(Variant::MtrDci);
        for _ in 0..3 {
            let (out, fb) = ex(&mut a, Some(&inp(0x18, 0x04, 0, 0, 0)), Demand::Standstill);
            assert_eq!(out[0] & 0x08, 0, "RESET = 0");
            assert_eq!(fb.state, AxisState::Fault);
        }
    }

    #[test]
    fn halt_and_quick_stop_bits() {
        let mut a = axis(Variant::MtrDci);
        ex(&mut a, Some(&inp(0x13, 0x91, 0, 0, 0)), Demand::Standstill);
        let (out, fb) = ex(&mut a, Some(&inp(0x13, 0x91, 0, 0, 0)), Demand::Halt);
        assert_eq!(out[0], 0x23);
        assert_eq!(out[1] & 0x01, 0, "CPOS.HALT = 0");
        assert_eq!(fb.state, AxisState::Stopping);
        let (out, fb) = ex(&mut a, Some(&inp(0x11, 0x84, 0, 0, 0)), Demand::QuickStop);
        assert_eq!(out[0] & 0x03, 0x01, "CCON.STOP = 0, ENABLE = 1");
        assert!(fb.done);
    }

    #[test]
    fn a_task_after_halt_first_clears_the_halted_one() {
        let mut a = axis(Variant::MtrDci);
        ex(
            &mut a,
            Some(&inp(0x13, 0x91, 1, 0, 0)),
            Demand::DriveRecord { number: 1 },
        );
        ex(&mut a, Some(&inp(0x13, 0x91, 1, 0, 0)), Demand::Halt);
        // Halted (SPOS.HALT = 0, MC = 0): CLEAR with HALT = 1 and no START.
        let d = Demand::DriveRecord { number: 2 };
        let (out, _) = ex(&mut a, Some(&inp(0x13, 0x80, 1, 0, 0)), d);
        assert_eq!(out[1], 0x41);
        // Ready again (TA6): the new record's START.
        let (out, _) = ex(&mut a, Some(&inp(0x13, 0x85, 1, 0, 0)), d);
        assert_eq!((out[1], out[2]), (0x03, 2));
    }

    #[test]
    fn unsupported_demands_are_refused_with_a_safe_image() {
        let mut a = axis(Variant::MtrDci);
        ex(&mut a, Some(&inp(0x13, 0x85, 0, 0, 0)), Demand::Standstill);
        let mut out = Image::default();
        let e = a.exchange(None, &Demand::Velocity { velocity: 5 }, &mut out);
        assert!(matches!(e, Err(AxisError::Unsupported(_))));
        assert_eq!(out.data[1] & 0x03, 0, "HALT = 0, no START");
        let e = a.exchange(None, &Demand::DriveRecord { number: 32 }, &mut out);
        assert!(matches!(e, Err(AxisError::Unsupported(_))));
    }

    #[test]
    fn force_and_speed_payloads_per_variant() {
        let mut a = axis(Variant::MtrDci);
        let ready = inp(0x53, 0x85, 0, 0, 0);
        let (out, _) = ex(
            &mut a,
            Some(&ready),
            Demand::Force {
                permille: 800,
                velocity_limit: 20_000,
            },
        );
        // Force: CDIR COM = 01 (0x02), 20 %, 80 % of the rated current on the MTR-DCI.
        assert_eq!(&out[1..4], &[0x03, 0x02, 20]);
        assert_eq!(i32::from_le_bytes([out[4], out[5], out[6], out[7]]), 80);
        let mut a = axis(Variant::Emca);
        let (out, _) = ex(&mut a, Some(&ready), Demand::Velocity { velocity: -3000 });
        assert_eq!(&out[1..4], &[0x03, 0x04, 100]);
        assert_eq!(i32::from_le_bytes([out[4], out[5], out[6], out[7]]), -3000);
    }

    #[test]
    fn teach_waits_for_the_drive_s_answers() {
        // EMCA: SPOS.TEACH follows CPOS.TEACH high; its fall means stored.
        let mut a = axis(Variant::Emca);
        let (out, _) = ex(&mut a, Some(&inp(0x13, 0x85, 0, 0, 0)), Demand::Teach);
        assert_eq!(out[1] & 0x20, 0x20);
        let (out, _) = ex(&mut a, Some(&inp(0x13, 0x85, 0, 0, 0)), Demand::Teach);
        assert_eq!(out[1] & 0x20, 0x20, "no answer yet");
        let (out, _) = ex(&mut a, Some(&inp(0x13, 0x8D, 0, 0, 0)), Demand::Teach);
        assert_eq!(out[1] & 0x20, 0, "answered: TEACH low");
        let (_, fb) = ex(&mut a, Some(&inp(0x13, 0x8D, 0, 0, 0)), Demand::Teach);
        assert!(!fb.done);
        let (_, fb) = ex(&mut a, Some(&inp(0x13, 0x85, 0, 0, 0)), Demand::Teach);
        assert!(fb.done);
    }

    #[test]
    fn jog_holds_the_direction_bit() {
        let mut a = axis(Variant::CmmoSt);
        let d = Demand::Jog {
            positive: false,
            velocity: 1000,
        };
        let mut b = [0x13, 0x85, 0, 0, 0, 0, 0, 0];
        let (out, _) = ex(&mut a, Some(&b), d);
        assert_eq!(out[1], 0x11, "JOGN + HALT");
        b[1] = 0x93;
        let (out, fb) = ex(&mut a, Some(&b), d);
        assert_eq!(out[1], 0x11);
        assert!(fb.done);
        assert_eq!(fb.state, AxisState::Moving);
    }
}
