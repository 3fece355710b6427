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
}
