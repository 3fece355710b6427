//! The client library: connect to a coordinator by prefix, read its state, send commands, and
//! receive events. No allocation per sample: the client keeps the newest sample borrowed from
//! shared memory and hands out references into it.
//!
//! A [`Client`] uses iceoryx2's single-threaded `ipc` service: create it on the thread that
//! uses it.

use crate::contract::{
    CommandReply, CommandRequest, EventRecord, MachineDescription, MachineState, status,
};
use crate::names::ServiceNames;
use crate::publisher::{ShmError, create_node};
use crate::request::name_str;
use core::time::Duration;
use iceoryx2::port::client::Client as IoxClient;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use iceoryx2::service::port_factory::request_response::PortFactory as ReqResFactory;
use std::time::Instant;

/// How long [`Client::next`] and [`Client::connect_timeout`] sleep between polls.
pub const POLL_INTERVAL: Duration = Duration::from_micros(200);
/// How long [`Client::command`] sleeps between polls for the reply.
pub const REPLY_POLL_INTERVAL: Duration = Duration::from_micros(50);

/// A command was accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Latched {
    /// The cycle whose SYNC latches the command.
    pub cycle: u64,
}

/// Why a command was not accepted: the coordinator's refusal or a transport failure.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Rejected {
    /// No such axis.
    #[error("there is no axis {0}")]
    UnknownAxis(u16),
    /// No such group.
    #[error("there is no group {0}")]
    UnknownGroup(u16),
    /// No such record.
    #[error("there is no record {0}")]
    UnknownRecord(u16),
    /// A value outside its limits.
    #[error("the value {value} lies outside the allowed range {min}..={max}")]
    OutOfRange {
        /// The value refused.
        value: i64,
        /// The lowest allowed.
        min: i64,
        /// The highest allowed.
        max: i64,
    },
    /// The axis or group is in the wrong state.
    #[error("the command does not fit the current state: {0}")]
    WrongState(String),
    /// Busy with another task.
    #[error("the target is busy with another task")]
    Busy,
    /// A fault must be acknowledged first.
    #[error("the target is faulted: acknowledge the fault first")]
    Faulted,
    /// The move cannot be planned.
    #[error("the move cannot be planned within the axes' limits")]
    Plan,
    /// The coordinator could not decode the request.
    #[error("the coordinator could not decode the request (unknown kind or target)")]
    BadRequest,
    /// The coordinator's queue (or this client's request slots) is full.
    #[error("the coordinator is overloaded: its command queue is full")]
    Overloaded,
    /// No reply in time.
    #[error("no reply from the coordinator in time")]
    Timeout,
    /// No coordinator serves the commands.
    #[error("no coordinator is serving commands")]
    Disconnected,
}

impl Rejected {
    /// The refusal a reply carries, or `None` for [`status::LATCHED`]. An unknown status (a
    /// newer coordinator) counts as [`Rejected::BadRequest`].
    pub fn from_reply(reply: &CommandReply) -> Option<Rejected> {
        let small = |v: i64| u16::try_from(v).unwrap_or(u16::MAX);
        Some(match reply.status {
            status::LATCHED => return None,
            status::UNKNOWN_AXIS => Rejected::UnknownAxis(small(reply.value)),
            status::UNKNOWN_GROUP => Rejected::UnknownGroup(small(reply.value)),
            status::UNKNOWN_RECORD => Rejected::UnknownRecord(small(reply.value)),
            status::OUT_OF_RANGE => Rejected::OutOfRange {
                value: reply.value,
                min: reply.min,
                max: reply.max,
            },
            status::WRONG_STATE => Rejected::WrongState(name_str(&reply.reason).to_owned()),
            status::BUSY => Rejected::Busy,
            status::FAULTED => Rejected::Faulted,
            status::PLAN => Rejected::Plan,
            status::OVERLOADED => Rejected::Overloaded,
            _ => Rejected::BadRequest,
        })
    }
}

/// The outcome a reply carries.
pub fn reply_result(reply: &CommandReply) -> Result<Latched, Rejected> {
    match Rejected::from_reply(reply) {
        None => Ok(Latched { cycle: reply.cycle }),
        Some(r) => Err(r),
    }
}

/// Why a client could not connect or read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ClientError {
    /// No coordinator serves this prefix.
    #[error("no motion coordinator is running under the prefix `{0}`")]
    NoCoordinator(String),
    /// The coordinator publishes another layout.
    #[error(
        "layout mismatch: this client expects `{expected}` but the coordinator publishes \
         `{found}`; the client and the coordinator were built from different contract versions \
         (rebuild the client against the coordinator's shm-api)"
    )]
    LayoutMismatch {
        /// The type name this client was built with.
        expected: String,
        /// The type name of the running coordinator's service.
        found: String,
    },
    /// Nothing new in time (the coordinator is there).
    #[error("no new state in time")]
    Timeout,
    /// The coordinator publishes no machine description (a stand-in, or one that failed to
    /// publish it), or none arrived in time.
    #[error("the coordinator published no machine description (or not in time)")]
    NoDescription,
    /// The coordinator went away (no publisher on the state service).
    #[error("the coordinator went away")]
    Disconnected,
    /// iceoryx2 failed otherwise.
    #[error("shared memory: {0}")]
    Shm(String),
}

impl From<ShmError> for ClientError {
    fn from(e: ShmError) -> Self {
        ClientError::Shm(e.to_string())
    }
}

/// A connection to one coordinator.
pub struct Client {
    prefix: String,
    // Ports and samples before the services and the node: fields drop in order.
    description: Option<Sample<ipc::Service, MachineDescription, ()>>,
    description_port: Option<Subscriber<ipc::Service, MachineDescription, ()>>,
    current: Option<Sample<ipc::Service, MachineState, ()>>,
    state: Subscriber<ipc::Service, MachineState, ()>,
    commands: IoxClient<ipc::Service, CommandRequest, (), CommandReply, ()>,
    log: Subscriber<ipc::Service, EventRecord, ()>,
    listener: Listener<ipc::Service>,
    state_service: PubSubFactory<ipc::Service, MachineState, ()>,
    _command_service: ReqResFactory<ipc::Service, CommandRequest, (), CommandReply, ()>,
    description_service: Option<PubSubFactory<ipc::Service, MachineDescription, ()>>,
    next_tag: u64,
    _node: Node<ipc::Service>,
}

impl core::fmt::Debug for Client {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Client")
            .field("prefix", &self.prefix)
            .finish_non_exhaustive()
    }
}

fn service_name(name: &str) -> Result<ServiceName, ClientError> {
    name.try_into().map_err(|e| {
        ClientError::Shm(format!(
            "invalid service name `{name}`: {}",
            crate::words(e)
        ))
    })
}

/// The payload type name of the existing publish-subscribe service `name`, if readable.
fn existing_type_name(node: &Node<ipc::Service>, name: &ServiceName) -> Option<String> {
    let details =
        ipc::Service::details(name, node.config(), MessagingPattern::PublishSubscribe).ok()??;
    Some(
        details
            .static_details
            .publish_subscribe()
            .message_type_details()
            .payload
            .type_name()
            .to_string(),
    )
}

fn type_name_of<T: ZeroCopySend>() -> String {
    // SAFETY: reading a type name has no preconditions (the unsafety is on implementers).
    unsafe { <T as ZeroCopySend>::type_name() }.to_owned()
}

/// Opens the publish-subscribe service `name` of payload `T`: a missing service means no
/// coordinator, another payload type a layout mismatch (named with the type found).
fn open_pubsub<T: ZeroCopySend + core::fmt::Debug + 'static>(
    node: &Node<ipc::Service>,
    name: &str,
    prefix: &str,
) -> Result<PubSubFactory<ipc::Service, T, ()>, ClientError> {
    let service = service_name(name)?;
    match node
        .service_builder(&service)
        .publish_subscribe::<T>()
        .open()
    {
        Ok(s) => Ok(s),
        Err(PublishSubscribeOpenError::DoesNotExist) => {
            Err(ClientError::NoCoordinator(prefix.to_owned()))
        }
        Err(PublishSubscribeOpenError::IncompatibleTypes) => Err(ClientError::LayoutMismatch {
            expected: type_name_of::<T>(),
            found: existing_type_name(node, &service)
                .unwrap_or_else(|| "an unreadable type".to_owned()),
        }),
        Err(e) => Err(ClientError::Shm(format!(
            "opening {name}: {}",
            crate::words(e)
        ))),
    }
}

impl Client {
    /// Connects to the coordinator under `prefix`; fails at once when none runs
    /// ([`ClientError::NoCoordinator`]) or it was built from another contract
    /// ([`ClientError::LayoutMismatch`]).
    pub fn connect(prefix: &str) -> Result<Client, ClientError> {
        let node = create_node()?;
        // A coordinator killed earlier still counts as a publisher until its node is removed.
        let _ = node.try_cleanup_dead_nodes();
        let names = ServiceNames::new(prefix);
        let no_coordinator = || ClientError::NoCoordinator(prefix.to_owned());

        let state_service = open_pubsub::<MachineState>(&node, &names.state, prefix)?;
        // The service outlives a dead coordinator while clients hold it open.
        if state_service.dynamic_config().number_of_publishers() == 0 {
            return Err(no_coordinator());
        }
        let command_service = node
            .service_builder(&service_name(&names.command)?)
            .request_response::<CommandRequest, CommandReply>()
            .open()
            .map_err(|e| match e {
                iceoryx2::service::builder::request_response::RequestResponseOpenError::DoesNotExist => no_coordinator(),
                iceoryx2::service::builder::request_response::RequestResponseOpenError::IncompatibleRequestOrResponseType => {
                    ClientError::LayoutMismatch {
                        expected: format!(
                            "{} -> {}",
                            type_name_of::<CommandRequest>(),
                            type_name_of::<CommandReply>()
                        ),
                        found: "another command layout".to_owned(),
                    }
                }
                e => ClientError::Shm(format!("opening {}: {}", names.command, crate::words(e))),
            })?;
        let log_service = open_pubsub::<EventRecord>(&node, &names.event_log, prefix)?;
        let events_service = node
            .service_builder(&service_name(&names.events)?)
            .event()
            .open()
            .map_err(|e| match e {
                iceoryx2::service::builder::event::EventOpenError::DoesNotExist => no_coordinator(),
                e => ClientError::Shm(format!("opening {}: {}", names.events, crate::words(e))),
            })?;

        let commands = command_service.client_builder().create().map_err(|e| {
            ClientError::Shm(format!("creating the command client: {}", crate::words(e)))
        })?;
        let log = log_service
            .subscriber_builder()
            .buffer_size(log_service.static_config().subscriber_max_buffer_size())
            .create()
            .map_err(|e| {
                ClientError::Shm(format!(
                    "creating the event-log subscriber: {}",
                    crate::words(e)
                ))
            })?;
        let listener = events_service.listener_builder().create().map_err(|e| {
            ClientError::Shm(format!("creating the events listener: {}", crate::words(e)))
        })?;
        // The state subscriber last: from its creation on, samples queue up in its buffer, so
        // nothing slow may come between it and the caller's first read.
        let state = state_service
            .subscriber_builder()
            .buffer_size(state_service.static_config().subscriber_max_buffer_size())
            .create()
            .map_err(|e| {
                ClientError::Shm(format!(
                    "creating the state subscriber: {}",
                    crate::words(e)
                ))
            })?;
        Ok(Client {
            prefix: prefix.to_owned(),
            description: None,
            description_port: None,
            current: None,
            state,
            commands,
            log,
            listener,
            state_service,
            _command_service: command_service,
            description_service: None,
            next_tag: 1,
            _node: node,
        })
    }

    /// Connects, retrying until a coordinator appears under `prefix` or `timeout` passes.
    /// A layout mismatch is reported at once (retrying cannot cure it).
    pub fn connect_timeout(prefix: &str, timeout: Duration) -> Result<Client, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            match Client::connect(prefix) {
                Ok(c) => return Ok(c),
                Err(e @ ClientError::LayoutMismatch { .. }) => return Err(e),
                Err(e) => {
                    let now = Instant::now();
                    if now >= deadline {
                        return Err(e);
                    }
                    // Connecting creates a node: retry at a relaxed pace.
                    std::thread::sleep((deadline - now).min(Duration::from_millis(20)));
                }
            }
        }
    }

    /// The prefix this client is connected to.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    fn receive_state(&mut self) -> bool {
        match self.state.receive() {
            Ok(Some(s)) => {
                // Replacing drops the previous sample, returning it to the publisher.
                self.current = Some(s);
                true
            }
            // A publisher that vanished mid-receive: nothing new.
            Ok(None) | Err(_) => false,
        }
    }

    fn current(&self) -> Option<&MachineState> {
        self.current.as_ref().map(|s| s.payload())
    }

    /// The newest state received so far, draining everything older; `None` before the
    /// first sample.
    pub fn latest(&mut self) -> Option<&MachineState> {
        while self.receive_state() {}
        self.current()
    }

    /// The next state not yet returned, in publishing order (a lagging client sees every
    /// sample as long as it lags less than the coordinator's state buffer). Sleeps
    /// [`POLL_INTERVAL`] between polls; [`ClientError::Timeout`] when nothing comes in time,
    /// [`ClientError::Disconnected`] when no coordinator publishes at that point.
    pub fn next(&mut self, timeout: Duration) -> Result<&MachineState, ClientError> {
        self.next_inner(timeout, false)
    }

    /// Like [`Client::next`], but sleeping on the `events` service until the coordinator's
    /// cycle thread signals a new state (event-driven: no polling, one wake-up per cycle).
    pub fn next_event_driven(&mut self, timeout: Duration) -> Result<&MachineState, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            if self.receive_state() {
                return self.current().ok_or(ClientError::Disconnected);
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(if self.coordinator_present() {
                    ClientError::Timeout
                } else {
                    ClientError::Disconnected
                });
            }
            // Any event wakes us; the state is what we look at. A missed signal costs at most
            // one POLL_INTERVAL (the wait is capped by it).
            self.listener
                .timed_wait(|_| {}, (deadline - now).min(POLL_INTERVAL * 10))
                .map_err(|e| {
                    ClientError::Shm(format!("waiting for a state: {}", crate::words(e)))
                })?;
        }
    }

    /// Like [`Client::next`], spinning instead of sleeping (lowest latency, one core busy).
    pub fn next_busy(&mut self, timeout: Duration) -> Result<&MachineState, ClientError> {
        self.next_inner(timeout, true)
    }

    fn next_inner(&mut self, timeout: Duration, busy: bool) -> Result<&MachineState, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            if self.receive_state() {
                return self.current().ok_or(ClientError::Disconnected);
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(if self.coordinator_present() {
                    ClientError::Timeout
                } else {
                    ClientError::Disconnected
                });
            }
            if busy {
                core::hint::spin_loop();
            } else {
                std::thread::sleep((deadline - now).min(POLL_INTERVAL));
            }
        }
    }

    /// The machine's description, which the coordinator publishes once at start: the first
    /// call subscribes to `PREFIX/description` and waits up to `timeout` for it (the
    /// coordinator hands it to a new subscriber within a poll of its command thread); later
    /// calls return it at once. Only clients that ask for it subscribe, so a monitor costs the
    /// service no subscriber slot.
    pub fn description(&mut self, timeout: Duration) -> Result<&MachineDescription, ClientError> {
        if self.description.is_none() {
            let sample = self.receive_description(timeout)?;
            self.description = Some(sample);
        }
        self.description
            .as_ref()
            .map(|s| s.payload())
            .ok_or(ClientError::NoDescription)
    }

    fn receive_description(
        &mut self,
        timeout: Duration,
    ) -> Result<Sample<ipc::Service, MachineDescription, ()>, ClientError> {
        let deadline = Instant::now() + timeout;
        if self.description_port.is_none() {
            let name = ServiceNames::new(&self.prefix).description;
            let service = match open_pubsub::<MachineDescription>(&self._node, &name, &self.prefix)
            {
                Ok(s) => s,
                // The state is there, so a coordinator runs: it just has no description.
                Err(ClientError::NoCoordinator(_)) => return Err(ClientError::NoDescription),
                Err(e) => return Err(e),
            };
            let port = service
                .subscriber_builder()
                .buffer_size(1)
                .create()
                .map_err(|e| {
                    ClientError::Shm(format!(
                        "creating the description subscriber: {}",
                        crate::words(e)
                    ))
                })?;
            self.description_service = Some(service);
            self.description_port = Some(port);
        }
        loop {
            if let Some(port) = &self.description_port
                && let Ok(Some(sample)) = port.receive()
            {
                return Ok(sample);
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(ClientError::NoDescription);
            }
            std::thread::sleep((deadline - now).min(POLL_INTERVAL));
        }
    }

    /// Whether a coordinator publishes the state (a crashed one counts until its node is
    /// cleaned up, which the next coordinator or client does when it starts).
    pub fn coordinator_present(&self) -> bool {
        self.state_service.dynamic_config().number_of_publishers() > 0
    }

    /// Clients subscribed to the coordinator's state now (this one included; a crashed
    /// client counts until its node is cleaned up).
    pub fn subscribers(&self) -> usize {
        self.state_service.dynamic_config().number_of_subscribers()
    }

    /// Sends `req` and waits up to `timeout` for the coordinator's reply. A request with tag 0
    /// gets the client's next tag.
    pub fn command(
        &mut self,
        req: &CommandRequest,
        timeout: Duration,
    ) -> Result<Latched, Rejected> {
        reply_result(&self.command_reply(req, timeout)?)
    }

    /// Like [`Client::command`], returning the raw reply (with the tag) when one arrives.
    pub fn command_reply(
        &mut self,
        req: &CommandRequest,
        timeout: Duration,
    ) -> Result<CommandReply, Rejected> {
        let mut r = *req;
        if r.tag == 0 {
            r.tag = self.next_tag;
            self.next_tag = self.next_tag.wrapping_add(1).max(1);
        }
        let deadline = Instant::now() + timeout;
        let pending = self.commands.send_copy(r).map_err(|e| match e {
            iceoryx2::port::client::RequestSendError::ExceedsMaxActiveRequests => {
                Rejected::Overloaded
            }
            _ => Rejected::Disconnected,
        })?;
        if pending.number_of_server_connections() == 0 {
            return Err(Rejected::Disconnected);
        }
        loop {
            // Read the connection before polling: a server replies and then drops its side, so
            // a reply sent before the disconnect is still found by this poll.
            let connected = pending.is_connected();
            match pending.receive() {
                Ok(Some(reply)) => {
                    let reply = *reply.payload();
                    if reply.tag != r.tag {
                        return Err(Rejected::BadRequest);
                    }
                    return Ok(reply);
                }
                Ok(None) => {}
                Err(_) => return Err(Rejected::Disconnected),
            }
            if !connected {
                return Err(Rejected::Disconnected);
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(Rejected::Timeout);
            }
            std::thread::sleep((deadline - now).min(REPLY_POLL_INTERVAL));
        }
    }

    /// The next event record, if one arrived (a new client first gets the last few records
    /// the coordinator published: the event-log history).
    pub fn next_event(&mut self) -> Option<EventRecord> {
        match self.log.receive() {
            Ok(Some(s)) => Some(*s.payload()),
            Ok(None) | Err(_) => None,
        }
    }

    /// Waits up to `timeout` for the next event record, sleeping on the events service.
    pub fn wait_event(&mut self, timeout: Duration) -> Result<Option<EventRecord>, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(rec) = self.next_event() {
                return Ok(Some(rec));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            self.listener
                .timed_wait(|_| {}, deadline - now)
                .map_err(|e| {
                    ClientError::Shm(format!("waiting for events: {}", crate::words(e)))
                })?;
        }
    }
}

#[cfg(test)]
mod words_tests {
    #[test]
    fn an_iceoryx2_error_reads_as_words() {
        let e = iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError::InsufficientPermissions;
        assert_eq!(crate::words(e), "insufficient permissions");
    }
}
