//! The Festo EMCA integrated drive on CANopen in its FHPP profile (seed 002 §5.1): the same
//! FHPP-over-CANopen adapter as the MTR-DCI ([`FestoNode`]) with the EMCA's communication
//! objects and its 5 ms internal cycle, EFPC on PDO2, EMCY on every new fault and on every
//! acknowledge, node guarding (loss = diagnostic 1Ch, EMCY 8130h).
//!
//! ```
//! use drivers::canopen::{Address, NodeId};
//! use drivers::sim::emca::Emca;
//! use drivers::time::Instant;
//! let d = Emca::new(NodeId::new(4).unwrap(), Instant::ZERO).unwrap();
//! assert_eq!(d.device().od().get_u32(Address::new(0x1000, 0)), Ok(0x12D));
//! ```

use crate::canopen::NodeId;
use crate::canopen::device::{CommProfile, PdoDefault};
use crate::catalog;
use crate::fhpp::Variant;
use crate::sim::fhpp_drive::DriveConfig;
use crate::sim::mtr_dci::{FestoNode, MTR_DCI_FHPP, SimError, festo_device, festo_identity};
use crate::time::Instant;

/// The EMCA's communication objects (§5.1): device type and vendor from the catalog, PDO1 (FHPP) and PDO2
/// (EFPC) valid and event-driven; PDO3/4 carry FHPP+ only when configured in FCT, which is not
/// modelled, so they are absent. Node guarding; the manual mentions no heartbeat, so there is
/// no 1017h.
pub const EMCA_FHPP: CommProfile = CommProfile {
    device_type: catalog::FESTO_FHPP_DEVICE_TYPE,
    identity: festo_identity(&catalog::EMCA),
    rpdo: [
        MTR_DCI_FHPP.rpdo[0],
        MTR_DCI_FHPP.rpdo[1],
        PdoDefault::ABSENT,
        PdoDefault::ABSENT,
    ],
    ..MTR_DCI_FHPP
};

/// The EMCA on CANopen.
#[derive(Debug)]
pub struct Emca(FestoNode);

impl Emca {
    /// A powered-on EMCA (boot-up queued) with the default axis.
    pub fn new(node: NodeId, now: Instant) -> Result<Emca, SimError> {
        Emca::with_config(node, DriveConfig::new(Variant::Emca), now)
    }

    /// A powered-on EMCA with a drive configuration of its own.
    pub fn with_config(node: NodeId, cfg: DriveConfig, now: Instant) -> Result<Emca, SimError> {
        if cfg.variant != Variant::Emca {
            return Err(SimError::Profile(cfg.variant));
        }
        // The EMCA manual lists no 1008h..100Ah (digest 002 §5.1): its firmware version is the
        // FHPP parameter PNU 100.
        FestoNode::build(node, &EMCA_FHPP, &[], cfg, false, now).map(Emca)
    }
}

festo_device!(Emca);
