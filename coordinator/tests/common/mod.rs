//! What the virtual-time tests of the embedded machine share.

use coordinator::config::{Config, EXAMPLE};
use coordinator::runtime::plan::{MachinePlan, plan};
use coordinator::runtime::run::RunOptions;

/// The embedded default machine, planned.
pub fn example() -> MachinePlan {
    plan(&Config::parse(EXAMPLE).expect("example parses")).expect("example plans")
}

/// A quiet virtual-time run with the demonstration (its chains as given), no end, no shared
/// memory, no capture.
pub fn demo(chains: bool) -> RunOptions {
    coordinator::runtime::synthetic::demo_options(chains)
}
