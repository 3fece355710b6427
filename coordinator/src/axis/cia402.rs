//! CiA 402 master side (placeholder until the axis work lands).

/// The master side of one CiA 402 drive.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Cia402Axis;
