//! The object dictionary as the SDO server and the PDO engine see it.
//!
//! [`ObjectAccess`] is the boundary between protocol code and storage: the SDO server reads and
//! writes through it, so a device's dictionary can veto a write with the abort code its manual
//! names (a value out of range, a write in the wrong state).

use super::{AbortCode, Address};

/// Read and write access to an object dictionary, by address.
pub trait ObjectAccess {
    /// The size in bytes of the object's current value (for an SDO upload's size indication).
    fn size(&self, addr: Address) -> Result<usize, AbortCode>;

    /// Copies up to `buf.len()` bytes of the value, starting at byte `offset`, into `buf`.
    /// Returns how many bytes were copied; segmented and block uploads read in pieces.
    fn read(&mut self, addr: Address, offset: usize, buf: &mut [u8]) -> Result<usize, AbortCode>;

    /// Writes a whole value. The dictionary checks access, length and range, and answers with
    /// the abort code that explains a refusal.
    fn write(&mut self, addr: Address, data: &[u8]) -> Result<(), AbortCode>;
}
