//! Builders for [`CommandRequest`], the [`Target`] of a command, and [`name_str`] for the
//! NUL-padded names of the contract.

use crate::contract::{
    CommandReply, CommandRequest, MAX_GROUP_AXES, buffer_mode, command_kind, status, target,
};

/// Which axes a command addresses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    /// One axis (its index in [`crate::contract::MachineState::axes`]).
    Axis(u16),
    /// Every axis of a group.
    Group(u16),
    /// Every axis.
    All,
}

/// The text of a NUL-padded name: up to the first NUL, and up to the last whole UTF-8
/// character when a peer wrote broken bytes (never panics).
pub fn name_str(bytes: &[u8]) -> &str {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    let bytes = bytes.get(..end).unwrap_or(bytes);
    match core::str::from_utf8(bytes) {
        Ok(s) => s,
        Err(e) => core::str::from_utf8(bytes.get(..e.valid_up_to()).unwrap_or(&[])).unwrap_or(""),
    }
}

/// A NUL-padded name field holding `s` (cut at `N` bytes, on a character boundary).
pub fn name_bytes<const N: usize>(s: &str) -> [u8; N] {
    let mut out = [0u8; N];
    let mut len = s.len().min(N);
    while !s.is_char_boundary(len) {
        len -= 1;
    }
    out[..len].copy_from_slice(&s.as_bytes()[..len]);
    out
}

impl CommandRequest {
    /// A request of `kind` with every other field zero (tag 0: the client sets its own).
    pub const fn new(kind: u16) -> CommandRequest {
        CommandRequest {
            tag: 0,
            kind,
            target: target::AXIS,
            percent: 0,
            axis: 0,
            group: 0,
            record: 0,
            sub: 0,
            buffer: buffer_mode::ABORTING,
            pnu: 0,
            reserved1: 0,
            value: 0,
            positions: [0; MAX_GROUP_AXES],
        }
    }

    /// The same request with `tag`.
    pub const fn with_tag(mut self, tag: u64) -> CommandRequest {
        self.tag = tag;
        self
    }

    fn targeted(kind: u16, t: Target) -> CommandRequest {
        let mut r = CommandRequest::new(kind);
        match t {
            Target::Axis(a) => {
                r.target = target::AXIS;
                r.axis = a;
            }
            Target::Group(g) => {
                r.target = target::GROUP;
                r.group = g;
            }
            Target::All => r.target = target::ALL,
        }
        r
    }

    /// Enable `t`.
    pub fn enable(t: Target) -> CommandRequest {
        Self::targeted(command_kind::ENABLE, t)
    }
    /// Disable `t`.
    pub fn disable(t: Target) -> CommandRequest {
        Self::targeted(command_kind::DISABLE, t)
    }
    /// Acknowledge the faults of `t`.
    pub fn acknowledge(t: Target) -> CommandRequest {
        Self::targeted(command_kind::ACKNOWLEDGE, t)
    }
    /// Home `t`.
    pub fn home(t: Target) -> CommandRequest {
        Self::targeted(command_kind::HOME, t)
    }
    /// Hold `t` (decelerate on the path; [`CommandRequest::resume`] continues).
    pub fn hold(t: Target) -> CommandRequest {
        Self::targeted(command_kind::HOLD, t)
    }
    /// Resume `t` after a hold.
    pub fn resume(t: Target) -> CommandRequest {
        Self::targeted(command_kind::RESUME, t)
    }
    /// Stop `t`.
    pub fn stop(t: Target) -> CommandRequest {
        Self::targeted(command_kind::STOP, t)
    }
    /// Quick stop `t`.
    pub fn quick_stop(t: Target) -> CommandRequest {
        Self::targeted(command_kind::QUICK_STOP, t)
    }
    /// Jog `axis` at `permille` ‰ of its velocity limit (signed; 0 stops).
    pub fn jog(axis: u16, permille: i16) -> CommandRequest {
        let mut r = Self::targeted(command_kind::JOG, Target::Axis(axis));
        r.value = i64::from(permille);
        r
    }
    /// Move `axis` to `position_micro` µunits at `percent` % of its limits.
    pub fn move_axis(axis: u16, position_micro: i64, percent: u8) -> CommandRequest {
        let mut r = Self::targeted(command_kind::MOVE_AXIS, Target::Axis(axis));
        r.positions[0] = position_micro;
        r.percent = percent;
        r
    }
    /// Move `group` to `positions_micro` (group order; at most [`MAX_GROUP_AXES`] are taken,
    /// the coordinator checks the count against the group) at `percent` %.
    pub fn move_group(group: u16, positions_micro: &[i64], percent: u8) -> CommandRequest {
        let mut r = Self::targeted(command_kind::MOVE_GROUP, Target::Group(group));
        for (dst, src) in r.positions.iter_mut().zip(positions_micro) {
            *dst = *src;
        }
        r.percent = percent;
        r
    }
    /// The same move, taking over from a running one as `mode` says ([`buffer_mode`]).
    pub const fn with_buffer(mut self, mode: u8) -> CommandRequest {
        self.buffer = mode;
        self
    }
    /// Set the feed override of `t` (an axis's own moves and jogs, a group's moves and its
    /// members', or everything) to `percent` %.
    pub fn set_override_of(t: Target, percent: u16) -> CommandRequest {
        let mut r = Self::targeted(command_kind::SET_OVERRIDE, t);
        r.value = i64::from(percent);
        r.percent = u8::try_from(percent).unwrap_or(u8::MAX);
        r
    }
    /// Start `group`'s record chain at `record`.
    pub fn start_chain(group: u16, record: u16) -> CommandRequest {
        let mut r = Self::targeted(command_kind::START_CHAIN, Target::Group(group));
        r.record = record;
        r
    }
    /// Set `group`'s feed override to `percent` %.
    pub fn set_override(group: u16, percent: u16) -> CommandRequest {
        let mut r = Self::targeted(command_kind::SET_OVERRIDE, Target::Group(group));
        r.value = i64::from(percent);
        r.percent = u8::try_from(percent).unwrap_or(u8::MAX);
        r
    }
    /// Read parameter `pnu`:`sub` of `axis` (the value arrives as a `PARAMETER` event).
    pub fn read_parameter(axis: u16, pnu: u16, sub: u8) -> CommandRequest {
        let mut r = Self::targeted(command_kind::READ_PARAMETER, Target::Axis(axis));
        r.pnu = pnu;
        r.sub = sub;
        r
    }
    /// Write `value` to parameter `pnu`:`sub` of `axis`.
    pub fn write_parameter(axis: u16, pnu: u16, sub: u8, value: i64) -> CommandRequest {
        let mut r = Self::read_parameter(axis, pnu, sub);
        r.kind = command_kind::WRITE_PARAMETER;
        r.value = value;
        r
    }
    /// Set input bit `bit` of the machine's input word to `value`.
    pub fn set_input(bit: u16, value: bool) -> CommandRequest {
        let mut r = CommandRequest::new(command_kind::SET_INPUT);
        r.target = target::ALL;
        r.record = bit;
        r.value = i64::from(value);
        r
    }

    /// The command's target, or `None` for an unknown target byte.
    pub fn target(&self) -> Option<Target> {
        match self.target {
            target::AXIS => Some(Target::Axis(self.axis)),
            target::GROUP => Some(Target::Group(self.group)),
            target::ALL => Some(Target::All),
            _ => None,
        }
    }
}

impl CommandReply {
    /// The reply to request `tag` of status `status` (every number zero).
    pub const fn new(tag: u64, status: u16) -> CommandReply {
        CommandReply {
            tag,
            cycle: 0,
            value: 0,
            min: 0,
            max: 0,
            status,
            reserved0: [0; 6],
            reason: [0; 48],
        }
    }
    /// Accepted: latches at the SYNC of `cycle`.
    pub const fn latched(tag: u64, cycle: u64) -> CommandReply {
        let mut r = CommandReply::new(tag, status::LATCHED);
        r.cycle = cycle;
        r
    }
    /// Refused with `status`, concerning `value` (an axis, group or record).
    pub const fn rejected(tag: u64, status: u16, value: i64) -> CommandReply {
        let mut r = CommandReply::new(tag, status);
        r.value = value;
        r
    }
    /// Refused: `value` lies outside `min..=max`.
    pub const fn out_of_range(tag: u64, value: i64, min: i64, max: i64) -> CommandReply {
        let mut r = CommandReply::new(tag, status::OUT_OF_RANGE);
        r.value = value;
        r.min = min;
        r.max = max;
        r
    }
    /// Refused: wrong state, for `reason` (cut at 48 bytes).
    pub fn wrong_state(tag: u64, reason: &str) -> CommandReply {
        let mut r = CommandReply::new(tag, status::WRONG_STATE);
        r.reason = name_bytes(reason);
        r
    }
    /// The reason text.
    pub fn reason_str(&self) -> &str {
        name_str(&self.reason)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_stop_at_nul_and_survive_broken_utf8() {
        assert_eq!(name_str(b"X1\0\0\0"), "X1");
        assert_eq!(name_str(b"full"), "full");
        assert_eq!(name_str(&[b'a', 0xC3, 0, 0]), "a");
        assert_eq!(name_str(&[]), "");
        let b: [u8; 4] = name_bytes("aé€");
        // 'a' (1) + 'é' (2) fit; '€' (3) would not.
        assert_eq!(name_str(&b), "aé");
    }

    #[test]
    fn builders_fill_the_documented_fields() {
        let r = CommandRequest::enable(Target::Group(3));
        assert_eq!(
            (r.kind, r.target, r.group),
            (command_kind::ENABLE, target::GROUP, 3)
        );
        assert_eq!(r.target(), Some(Target::Group(3)));
        let r = CommandRequest::quick_stop(Target::All);
        assert_eq!((r.kind, r.target), (command_kind::QUICK_STOP, target::ALL));
        let r = CommandRequest::jog(2, -500);
        assert_eq!((r.kind, r.axis, r.value), (command_kind::JOG, 2, -500));
        let r = CommandRequest::move_axis(1, 1_500_000, 40);
        assert_eq!((r.positions[0], r.percent), (1_500_000, 40));
        let r = CommandRequest::move_group(0, &[1, 2, 3, 4, 5, 6, 7, 8, 9], 100);
        assert_eq!(r.positions, [1, 2, 3, 4, 5, 6, 7, 8]);
        let r = CommandRequest::start_chain(1, 7);
        assert_eq!(
            (r.kind, r.group, r.record),
            (command_kind::START_CHAIN, 1, 7)
        );
        let r = CommandRequest::set_override(0, 150);
        assert_eq!((r.value, r.percent), (150, 150));
        let r = CommandRequest::write_parameter(4, 0x1234, 2, -9);
        assert_eq!(
            (r.kind, r.axis, r.pnu, r.sub, r.value),
            (command_kind::WRITE_PARAMETER, 4, 0x1234, 2, -9)
        );
        let r = CommandRequest::set_input(5, true);
        assert_eq!((r.kind, r.record, r.value), (command_kind::SET_INPUT, 5, 1));
        let mut bad = CommandRequest::new(command_kind::STOP);
        bad.target = 9;
        assert_eq!(bad.target(), None);
    }

    #[test]
    fn wrong_state_reason_is_cut_on_a_boundary() {
        let long = "é".repeat(40);
        let r = CommandReply::wrong_state(1, &long);
        assert_eq!(r.reason_str().len(), 48);
        assert_eq!(r.status, status::WRONG_STATE);
    }
}
