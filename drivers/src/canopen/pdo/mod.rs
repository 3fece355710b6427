//! Process data objects (CiA 301 §7.2.2): mapping and bit-granular packing, communication
//! parameters, the sans-I/O transmit and receive engines, and the SDO plan that configures a
//! remote node's PDO with read-back verification.

pub mod comm;
pub mod config;
pub mod engine;
pub mod mapping;

pub use comm::{CobId, CommError, CommParams, TransmissionType};
pub use config::{ConfigPlan, ConfigStep, PdoDirection, PdoSettings, PlanError, VerifyError};
pub use engine::{Rpdo, RpdoEvent, Tpdo};
pub use mapping::{
    Mapping, MappingEntry, MappingError, PdoError, PdoValues, Positions, sign_extend,
};
