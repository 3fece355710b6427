//! Node-IDs, object addresses and the pre-defined connection set (CiA 301 §7.3.3): COB-ID =
//! function code (bits 10..7) + node-ID (bits 6..0).

/// A CANopen node-ID, 1..=127.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct NodeId(u8);

impl NodeId {
    /// The node-ID `id`, or `None` outside 1..=127.
    pub const fn new(id: u8) -> Option<NodeId> {
        if id >= 1 && id <= 127 {
            Some(NodeId(id))
        } else {
            None
        }
    }
    /// The raw node-ID.
    pub const fn get(self) -> u8 {
        self.0
    }
}

impl core::fmt::Display for NodeId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// An object dictionary address: index and sub-index.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Address {
    /// The 16-bit index.
    pub index: u16,
    /// The 8-bit sub-index.
    pub sub: u8,
}

impl Address {
    /// `index:sub`.
    pub const fn new(index: u16, sub: u8) -> Address {
        Address { index, sub }
    }
    /// The index as it appears on the wire in SDO frames (bytes 1..=2 little-endian, byte 3 sub).
    pub const fn to_sdo_bytes(self) -> [u8; 3] {
        let i = self.index.to_le_bytes();
        [i[0], i[1], self.sub]
    }
    /// Reads an address from SDO bytes 1..=3.
    pub const fn from_sdo_bytes(b: [u8; 3]) -> Address {
        Address {
            index: u16::from_le_bytes([b[0], b[1]]),
            sub: b[2],
        }
    }
}

impl core::fmt::Display for Address {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{:04X}h:{:02X}h", self.index, self.sub)
    }
}

/// The function codes of the pre-defined connection set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FunctionCode {
    /// NMT module control, COB-ID 000h.
    Nmt,
    /// SYNC (080h) when the node bits are 0, EMCY (080h + node) otherwise.
    SyncEmcy,
    /// TIME stamp, 100h.
    Time,
    /// Transmit PDO 1..4 (180h, 280h, 380h, 480h + node).
    Tpdo(u8),
    /// Receive PDO 1..4 (200h, 300h, 400h, 500h + node).
    Rpdo(u8),
    /// SDO server to client (580h + node).
    SdoTx,
    /// SDO client to server (600h + node).
    SdoRx,
    /// NMT error control: boot-up, heartbeat, node guarding (700h + node).
    NmtErrorControl,
}

impl FunctionCode {
    /// The base COB-ID (node-ID 0).
    pub const fn base(self) -> u16 {
        match self {
            FunctionCode::Nmt => 0x000,
            FunctionCode::SyncEmcy => 0x080,
            FunctionCode::Time => 0x100,
            FunctionCode::Tpdo(n) => 0x080 + 0x100 * (n as u16),
            FunctionCode::Rpdo(n) => 0x100 + 0x100 * (n as u16),
            FunctionCode::SdoTx => 0x580,
            FunctionCode::SdoRx => 0x600,
            FunctionCode::NmtErrorControl => 0x700,
        }
    }
    /// The COB-ID of this function for `node`.
    pub const fn cob_id(self, node: NodeId) -> u16 {
        self.base() + node.0 as u16
    }
    /// Splits a COB-ID of the pre-defined connection set into function code and node bits.
    pub const fn split(cob_id: u16) -> Option<(FunctionCode, u8)> {
        let node = (cob_id & 0x7F) as u8;
        let fc = match cob_id >> 7 {
            0x0 if node == 0 => FunctionCode::Nmt,
            0x1 => FunctionCode::SyncEmcy,
            0x2 if node == 0 => FunctionCode::Time,
            0x3 => FunctionCode::Tpdo(1),
            0x4 => FunctionCode::Rpdo(1),
            0x5 => FunctionCode::Tpdo(2),
            0x6 => FunctionCode::Rpdo(2),
            0x7 => FunctionCode::Tpdo(3),
            0x8 => FunctionCode::Rpdo(3),
            0x9 => FunctionCode::Tpdo(4),
            0xA => FunctionCode::Rpdo(4),
            0xB => FunctionCode::SdoTx,
            0xC => FunctionCode::SdoRx,
            0xE => FunctionCode::NmtErrorControl,
            _ => return None,
        };
        Some((fc, node))
    }
}

/// Default COB-IDs used throughout the stack.
pub mod ids {
    /// NMT module control.
    pub const NMT: u16 = 0x000;
    /// SYNC (default of 1005h).
    pub const SYNC: u16 = 0x080;
    /// EMCY base (+ node-ID).
    pub const EMCY: u16 = 0x080;
    /// SDO server-to-client base (+ node-ID).
    pub const SDO_TX: u16 = 0x580;
    /// SDO client-to-server base (+ node-ID).
    pub const SDO_RX: u16 = 0x600;
    /// NMT error control base (+ node-ID).
    pub const NMT_ERROR_CONTROL: u16 = 0x700;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connection_set() {
        let n5 = NodeId::new(5).unwrap();
        assert_eq!(FunctionCode::Tpdo(1).cob_id(n5), 0x185);
        assert_eq!(FunctionCode::Rpdo(4).cob_id(n5), 0x505);
        assert_eq!(FunctionCode::Tpdo(4).cob_id(n5), 0x485);
        assert_eq!(FunctionCode::split(0x581), Some((FunctionCode::SdoTx, 1)));
        assert_eq!(
            FunctionCode::split(0x080),
            Some((FunctionCode::SyncEmcy, 0))
        );
        assert_eq!(FunctionCode::split(0x000), Some((FunctionCode::Nmt, 0)));
        assert_eq!(
            FunctionCode::split(0x77F),
            Some((FunctionCode::NmtErrorControl, 127))
        );
        assert_eq!(NodeId::new(0), None);
        assert_eq!(NodeId::new(128), None);
    }

    #[test]
    fn sdo_address_bytes() {
        let a = Address::new(0x1018, 2);
        assert_eq!(a.to_sdo_bytes(), [0x18, 0x10, 0x02]);
        assert_eq!(Address::from_sdo_bytes([0x18, 0x10, 0x02]), a);
        assert_eq!(a.to_string(), "1018h:02h");
    }
}
