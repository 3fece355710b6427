//! The iceoryx2 service names of the contract, all under one prefix (default
//! [`crate::DEFAULT_PREFIX`]), so that several coordinators (and parallel tests) can share a
//! machine without seeing each other.

/// The five service names under a prefix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    /// `PREFIX/state`: publish-subscribe, [`crate::contract::MachineState`], history 1.
    pub state: String,
    /// `PREFIX/command`: request-response, [`crate::contract::CommandRequest`] →
    /// [`crate::contract::CommandReply`].
    pub command: String,
    /// `PREFIX/events`: event service, the event id is [`crate::contract::EventRecord::id`].
    pub events: String,
    /// `PREFIX/event-log`: publish-subscribe, [`crate::contract::EventRecord`], history 16.
    pub event_log: String,
    /// `PREFIX/description`: publish-subscribe, [`crate::contract::MachineDescription`],
    /// published once at start, history 1.
    pub description: String,
}

impl ServiceNames {
    /// The names under `prefix`.
    pub fn new(prefix: &str) -> ServiceNames {
        ServiceNames {
            state: format!("{prefix}/state"),
            command: format!("{prefix}/command"),
            events: format!("{prefix}/events"),
            event_log: format!("{prefix}/event-log"),
            description: format!("{prefix}/description"),
        }
    }
}

/// The longest prefix: iceoryx2 keeps a service's name in its files' names, which the file
/// system bounds; 64 leaves room for the longest suffix (`/description`) and its own additions.
pub const PREFIX_MAX_LEN: usize = 64;

/// Checks a prefix a user typed (`--prefix`, `--shm-prefix`): 1 to [`PREFIX_MAX_LEN`] ASCII
/// letters, digits, `-`, `_`, `.`, with `/` between non-empty parts. Returns it unchanged, so
/// that it serves as a clap value parser; the error says what is allowed.
pub fn check_prefix(prefix: &str) -> Result<String, String> {
    let allowed = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.');
    let ok = !prefix.is_empty()
        && prefix.len() <= PREFIX_MAX_LEN
        && prefix
            .split('/')
            .all(|part| !part.is_empty() && part.chars().all(allowed));
    if ok {
        Ok(prefix.to_owned())
    } else {
        Err(format!(
            "a service prefix is 1 to {PREFIX_MAX_LEN} letters, digits, `-`, `_` or `.`, with `/` between non-empty parts"
        ))
    }
}

impl Default for ServiceNames {
    fn default() -> Self {
        ServiceNames::new(crate::DEFAULT_PREFIX)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_hang_under_the_prefix() {
        let n = ServiceNames::new("cell-2");
        assert_eq!(n.state, "cell-2/state");
        assert_eq!(n.command, "cell-2/command");
        assert_eq!(n.events, "cell-2/events");
        assert_eq!(n.event_log, "cell-2/event-log");
        assert_eq!(n.description, "cell-2/description");
        assert_eq!(ServiceNames::default().state, "motion/state");
    }

    #[test]
    fn prefixes_are_checked() {
        for good in ["motion", "cell-2", "t-run_cli.x-123", "plant/cell-2"] {
            assert_eq!(check_prefix(good).as_deref(), Ok(good));
        }
        let long = "a".repeat(PREFIX_MAX_LEN + 1);
        for bad in [
            "",
            "/motion",
            "motion/",
            "a//b",
            "a b",
            "a:b",
            "ä",
            long.as_str(),
        ] {
            assert!(check_prefix(bad).is_err(), "{bad}");
        }
    }
}
