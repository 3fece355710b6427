//! The coordinator's run time around the cycle: booting the drives and the non-real-time
//! services that talk to the cycle thread through lock-free queues.

pub mod boot;
pub mod services;
