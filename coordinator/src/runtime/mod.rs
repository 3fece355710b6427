//! The std runtime around the pure cycle: the real-time thread, the drives' I/O threads.
pub mod modbus;
pub mod rt;
