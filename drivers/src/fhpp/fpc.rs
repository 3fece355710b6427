//! placeholder
/// x
pub enum Channel {
    /// x
    Classic,
    /// x
    Enhanced,
}
