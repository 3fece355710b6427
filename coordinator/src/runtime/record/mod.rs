//! Record and replay: everything that enters the cycle, kept compactly so that the cycle can be
//! run again on it and every frame it sent and every state it published checked bit for bit.
//!
//! - [`format`](mod@format): the file's bytes (sans I/O).
//! - [`recorder`]: `coordinator run --record FILE`, the cycle thread's side and the writer.
//! - [`replay`]: `coordinator replay FILE`, the cycle run again and compared.

pub mod format;
pub mod recorder;
pub mod replay;
