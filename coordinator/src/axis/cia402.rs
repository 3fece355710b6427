//! CiA 402 master side (in progress).

/// Which PDO layout the drive uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Layout {
    /// TLC5xx.
    Tlc5xx,
    /// MTR-DCI.
    MtrDci,
}
impl Layout {
    /// rx.
    pub fn rx_len(self) -> usize {
        7
    }
    /// tx.
    pub fn tx_len(self) -> usize {
        7
    }
}
/// The master side of one CiA 402 drive.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Cia402Axis {
    layout: Layout,
}
impl Cia402Axis {
    /// new
    pub fn new(layout: Layout, _c: u32) -> Self {
        Cia402Axis { layout }
    }
    /// layout
    pub fn layout(&self) -> Layout {
        self.layout
    }
    /// reset
    pub fn reset(&mut self) {}
    /// exchange
    pub fn exchange(
        &mut self,
        _i: Option<&[u8]>,
        _d: &super::Demand,
        _o: &mut super::Image,
    ) -> Result<super::Feedback, super::AxisError> {
        Err(super::AxisError::Unsupported("CiA 402 (not yet)"))
    }
}
