//! The runtime (std): what runs the cycle on a real machine or in virtual time.
//!
//! - [`plan`]: configuration → cycle setups, record tables, boot plans;
//! - [`sim`]: the simulated drives behind a plan;
//! - [`script`]: the built-in demonstration client;
//! - [`stepper`]: one step of the cycle with its frame buffers and counters;
//! - [`cycle_loop`]: the one cycle iteration, behind the I/O seam both clocks implement;
//! - [`run`]: `coordinator run`: the choice of clock, the summary and the operator's lines;
//! - [`virtual_clock`]: simulated drives in lockstep with the cycle, deterministic;
//! - [`real_clock`]: the cycle thread, the buses as configured, the services;
//! - [`nodes`]: the drives' boot and lifecycle on every bus, sans-I/O;
//! - [`ticker`]: absolute-deadline wake-ups; [`realtime_thread`]: SCHED_FIFO, mlockall, CPU
//!   pinning; [`signals`]: the stop flag every stop signal sets;
//! - [`modbus`]: the CMMO-ST exchange off the cycle thread (its hand-over is `handover`'s
//!   triple buffer);
//! - [`boot`]: drive boot over SDO; [`services`]: the non-real-time tasks on embassy;
//! - [`shm`]: the machine state, commands and events over shared memory (`shm-api`);
//! - [`capture`]: `--capture DIR`, a candump log and a pcap per bus, off the cycle thread.

pub mod boot;
pub mod capture;
pub mod cycle_loop;
pub mod ethercat;
pub mod modbus;
pub mod nodes;
pub mod plan;
pub mod real_clock;
pub mod realtime_thread;
pub mod record;
pub mod run;
pub mod scenario;
pub mod script;
pub mod services;
pub mod shm;
pub mod signals;
pub mod sim;
pub mod stepper;
pub mod synthetic;
pub mod ticker;
pub mod virtual_clock;
