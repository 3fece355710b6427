//! FHPP master side (placeholder until the axis work lands).

/// The master side of one FHPP drive.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FhppAxis;
