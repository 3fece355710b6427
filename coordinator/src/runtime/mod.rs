//! The runtime (std): what runs the cycle on a real machine or in virtual time.
//!
//! - [`plan`]: configuration → cycle setups, record tables, boot plans;
//! - [`sim`]: the simulated drives behind a plan;
//! - [`script`]: the built-in demonstration client;
//! - [`cycle_loop`]: the one cycle iteration, behind the I/O seam both clocks implement:
//! - [`run`]: `coordinator run`, and the virtual clock (simulated drives in lockstep);
//! - [`realtime`]: the real clock (the cycle thread, the buses as configured, the services);
//! - [`nodes`]: the drives' boot and lifecycle on every bus, sans-I/O;
//! - [`rt`]: absolute-deadline wake-ups, SCHED_FIFO, mlockall, Ctrl-C;
//! - [`modbus`]: the CMMO-ST exchange off the cycle thread;
//! - [`boot`]: drive boot over SDO; [`services`]: the non-real-time tasks on embassy;
//! - [`shm`]: the machine state, commands and events over shared memory (`shm-api`);
//! - [`capture`]: `--capture DIR`, a candump log and a pcap per bus, off the cycle thread.

pub mod boot;
pub mod capture;
pub mod cycle_loop;
pub mod modbus;
pub mod nodes;
pub mod plan;
pub mod realtime;
pub mod rt;
pub mod run;
pub mod script;
pub mod services;
pub mod shm;
pub mod sim;
pub mod synthetic;
