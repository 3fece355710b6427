//! EtherCAT, subdevice side, sans-I/O (digest `ethercat-digest.md`): what a simulated
//! EtherCAT subdevice needs to answer a real master such as ethercrab.
//!
//! - [`frame`]: Ethernet II frames of EtherType 88A4h and their datagrams, parsed in place.
//! - [`register`]: the ESC registers and bit layouts a master uses.
//! - [`esm`]: the EtherCAT state machine's states, AL status codes and transition table.
//! - [`sii`]: the SII EEPROM image (identity, mailboxes, categories) and its CRC.
//! - [`esc`]: a simulated slave controller: addressing, working counters, sync managers,
//!   FMMUs, the SII interface, AL control and status, the SM watchdog, the DC subset.
//! - [`coe`]: the mailbox and CANopen over EtherCAT: SDO server and emergencies.
//! - [`segment`]: several subdevices in wiring order, one frame through all of them.
//! - [`wire_time`]: how long a cycle's frames take on a 100 Mbit/s line, and the round trip.
//! - [`raw`] (`std`, Linux): frames on a network interface through an `AF_PACKET` socket.
//! - [`pcap`] (`std`): captures of Ethernet frames that Wireshark decodes as EtherCAT.
//!
//! The EMCA's EtherCAT application (its ESM checks, object dictionary and process data) is
//! [`crate::sim::emca_ec`].

pub mod coe;
pub mod esc;
pub mod esm;
pub mod frame;
#[cfg(feature = "std")]
pub mod pcap;
#[cfg(all(feature = "std", target_os = "linux"))]
pub mod raw;
pub mod register;
pub mod segment;
pub mod sii;
pub mod wire_time;
