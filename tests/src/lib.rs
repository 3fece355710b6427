//! Integration tests across the workspace's crates live in `tests/tests/`; this library holds
//! the helpers they share.
