//! The runtime (std): what runs the cycle on a real machine or in virtual time.
//!
//! - [`plan`]: configuration → cycle setups, record tables, boot plans;
//! - [`sim`]: the simulated drives behind a plan;
//! - [`script`]: the built-in demonstration client;
//! - [`run`]: `coordinator run` in virtual time, and the cycle iteration shared with
//! - [`realtime`]: the real-time threads;
//! - [`rt`]: absolute-deadline wake-ups, SCHED_FIFO, mlockall, Ctrl-C;
//! - [`modbus`]: the CMMO-ST exchange off the cycle thread;
//! - [`boot`]: drive boot over SDO; [`services`]: the non-real-time tasks on embassy;
//! - [`shm`]: the machine state, commands and events over shared memory (`shm-api`).

pub mod boot;
pub mod capture;
pub mod modbus;
pub mod plan;
pub mod realtime;
pub mod rt;
pub mod run;
pub mod script;
pub mod services;
pub mod shm;
pub mod sim;
pub mod synthetic;
