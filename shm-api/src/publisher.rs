//! The coordinator's side: the state publisher (one sample per cycle), the command server, the
//! event publisher, the description publisher (one sample at start), and [`cleanup_dead_nodes`].
//!
//! Everything here uses iceoryx2's single-threaded `ipc` service: create each object on the
//! thread that uses it (the cycle thread owns the [`StatePublisher`], the services thread the
//! [`CommandServer`], [`EventPublisher`] and [`DescriptionPublisher`]).

use crate::contract::{
    CommandReply, CommandRequest, EventRecord, LAYOUT_HASH, LAYOUT_VERSION, MachineDescription,
    MachineState,
};
use crate::names::ServiceNames;
use core::ops::{Deref, DerefMut};
use iceoryx2::active_request::ActiveRequest;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::server::Server;
use iceoryx2::prelude::*;
use iceoryx2::sample_mut::SampleMut;

/// Why a shared-memory operation failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ShmError {
    /// The prefix makes an invalid iceoryx2 service name.
    #[error("invalid service name `{name}`: {reason}")]
    Name {
        /// The name.
        name: String,
        /// iceoryx2's objection.
        reason: String,
    },
    /// iceoryx2 refused a step.
    #[error("{step} failed: {reason}")]
    Iceoryx {
        /// What was being done.
        step: &'static str,
        /// iceoryx2's error.
        reason: String,
    },
}

impl ShmError {
    pub(crate) fn iox(step: &'static str, e: impl core::fmt::Display) -> ShmError {
        ShmError::Iceoryx {
            step,
            reason: crate::words(e),
        }
    }
}

/// Capacities of the services the coordinator creates. Clients open the services with
/// whatever the coordinator created (they ask for nothing), so these are the only knobs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PublisherSettings {
    /// Subscribers of `state` and `event-log` at once (clients), default 16.
    pub max_subscribers: usize,
    /// Samples a state subscriber buffers before the oldest is overwritten (safe overflow),
    /// default 64: a client may lag this many cycles without losing a sample.
    pub state_buffer: usize,
    /// Event records a late joiner gets at once, and that a subscriber buffers, default 16.
    pub event_history: usize,
    /// Command clients at once, default 16.
    pub max_clients: usize,
    /// iceoryx2 nodes per service, default 32.
    pub max_nodes: usize,
}

impl Default for PublisherSettings {
    fn default() -> Self {
        PublisherSettings {
            max_subscribers: 16,
            state_buffer: 64,
            event_history: 16,
            max_clients: 16,
            max_nodes: 32,
        }
    }
}

fn service_name(name: &str) -> Result<ServiceName, ShmError> {
    name.try_into().map_err(|e| ShmError::Name {
        name: name.to_owned(),
        reason: crate::words(e),
    })
}

/// Creates an iceoryx2 node for the contract's services, without signal handlers (the
/// coordinator and the clients handle their own signals). Logs at `Error` unless
/// `IOX2_LOG_LEVEL` says otherwise.
pub fn create_node() -> Result<Node<ipc::Service>, ShmError> {
    create_node_with(SignalHandlingMode::Disabled)
}

/// Like [`create_node`] with iceoryx2's signal handling `mode`: with
/// [`SignalHandlingMode::HandleTerminationRequests`], `node.wait(..)` reports SIGINT and
/// SIGTERM, so a simple process can stop cleanly and remove its services.
pub fn create_node_with(mode: SignalHandlingMode) -> Result<Node<ipc::Service>, ShmError> {
    static LOG: std::sync::Once = std::sync::Once::new();
    // The missing-config warning would otherwise go to every tool's stderr.
    LOG.call_once(|| set_log_level_from_env_or(LogLevel::Error));
    NodeBuilder::new()
        .signal_handling_mode(mode)
        .create::<ipc::Service>()
        .map_err(|e| ShmError::iox("creating the iceoryx2 node", e))
}

/// Removes the resources that crashed processes left (their nodes, ports and shared memory),
/// so their slots in the services are free again. The coordinator calls it at start. Returns
/// how many dead nodes were removed.
pub fn cleanup_dead_nodes() -> Result<u64, ShmError> {
    let node = create_node()?;
    Ok(cleanup_dead_nodes_with(&node))
}

/// Like [`cleanup_dead_nodes`] on an existing node: the coordinator's services thread calls it
/// now and then (a crashed client holds its port slots until someone does). Returns how many
/// dead nodes were removed.
pub fn cleanup_dead_nodes_with(node: &Node<ipc::Service>) -> u64 {
    node.try_cleanup_dead_nodes().cleanups
}

/// Publishes the [`MachineState`] on `PREFIX/state`, once per cycle.
///
/// History 1 (a late joiner gets the latest state with the publisher's next send, that is
/// within a cycle, and then every later one), safe overflow (a slow client loses
/// its oldest samples and never blocks the publisher), no notification (clients poll). Loan,
/// write and send allocate nothing.
pub struct StatePublisher {
    publisher: Publisher<ipc::Service, MachineState, ()>,
}

impl core::fmt::Debug for StatePublisher {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("StatePublisher").finish_non_exhaustive()
    }
}

impl StatePublisher {
    /// Creates (or joins) `names.state`.
    pub fn create(
        node: &Node<ipc::Service>,
        names: &ServiceNames,
        settings: &PublisherSettings,
    ) -> Result<StatePublisher, ShmError> {
        let service = node
            .service_builder(&service_name(&names.state)?)
            .publish_subscribe::<MachineState>()
            .max_publishers(1)
            .max_subscribers(settings.max_subscribers)
            .max_nodes(settings.max_nodes)
            .history_size(1)
            .subscriber_max_buffer_size(settings.state_buffer)
            .subscriber_max_borrowed_samples(2)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(|e| ShmError::iox("opening the state service", e))?;
        let publisher = service
            .publisher_builder()
            .max_loaned_samples(1)
            .create()
            .map_err(|e| ShmError::iox("creating the state publisher", e))?;
        Ok(StatePublisher { publisher })
    }

    /// A sample to fill, zeroed except [`MachineState::version`] and
    /// [`MachineState::layout_hash`].
    pub fn loan(&mut self) -> Result<StateSample<'_>, ShmError> {
        let mut sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| ShmError::iox("loaning a state sample", e))?;
        // SAFETY: `MachineState` is plain integers and integer arrays (`repr(C)`, no
        // references, no enums), so all-zero bytes are a valid value; zeroing in place avoids
        // building a 17 KiB value on the stack and copying it.
        let sample = unsafe {
            sample.payload_mut().as_mut_ptr().write_bytes(0, 1);
            sample.assume_init()
        };
        let mut s = StateSample {
            sample,
            _publisher: core::marker::PhantomData,
        };
        s.version = LAYOUT_VERSION;
        s.layout_hash = LAYOUT_HASH;
        Ok(s)
    }

    /// Publishes a copy of `state` (loan, copy, send).
    pub fn publish(&mut self, state: &MachineState) -> Result<(), ShmError> {
        let mut s = self.loan()?;
        *s = *state;
        s.send()
    }
}

/// A loaned state sample: write it through `Deref<Target = MachineState>`, then
/// [`StateSample::send`]. Dropping it unsent discards it.
pub struct StateSample<'a> {
    sample: SampleMut<ipc::Service, MachineState, ()>,
    _publisher: core::marker::PhantomData<&'a mut StatePublisher>,
}

impl StateSample<'_> {
    /// Delivers the sample to every client.
    pub fn send(self) -> Result<(), ShmError> {
        self.sample
            .send()
            .map(|_| ())
            .map_err(|e| ShmError::iox("sending a state sample", e))
    }
}

impl Deref for StateSample<'_> {
    type Target = MachineState;
    fn deref(&self) -> &MachineState {
        self.sample.payload()
    }
}

impl DerefMut for StateSample<'_> {
    fn deref_mut(&mut self) -> &mut MachineState {
        self.sample.payload_mut()
    }
}

/// Publishes the [`MachineDescription`] on `PREFIX/description`, once, at start.
///
/// History 1, so a client that subscribes later still receives it: iceoryx2 hands the history
/// to a new subscriber when the publisher next updates its connections, which
/// [`DescriptionPublisher::update_connections`] does (the coordinator's command thread calls it
/// with every poll). The payload is large (about 1.3 MB: every record table at full size) and
/// sent once, so the publisher keeps one sample in shared memory rather than one per
/// subscriber's buffer; a second [`DescriptionPublisher::publish`] finds no sample to loan.
pub struct DescriptionPublisher {
    publisher: Publisher<ipc::Service, MachineDescription, ()>,
}

impl core::fmt::Debug for DescriptionPublisher {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("DescriptionPublisher")
            .finish_non_exhaustive()
    }
}

impl DescriptionPublisher {
    /// Creates (or joins) `names.description`.
    pub fn create(
        node: &Node<ipc::Service>,
        names: &ServiceNames,
        settings: &PublisherSettings,
    ) -> Result<DescriptionPublisher, ShmError> {
        let service = node
            .service_builder(&service_name(&names.description)?)
            .publish_subscribe::<MachineDescription>()
            .max_publishers(1)
            .max_subscribers(settings.max_subscribers)
            .max_nodes(settings.max_nodes)
            .history_size(1)
            .subscriber_max_buffer_size(1)
            .subscriber_max_borrowed_samples(1)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(|e| ShmError::iox("opening the description service", e))?;
        let publisher = service
            .publisher_builder()
            .max_loaned_samples(1)
            // One sample: the history and every subscriber share it (see the type's docs).
            .override_sample_preallocation(|_| 1)
            .create()
            .map_err(|e| ShmError::iox("creating the description publisher", e))?;
        Ok(DescriptionPublisher { publisher })
    }

    /// Publishes `description` (loan, copy in place, send). Once: the publisher holds one
    /// sample.
    pub fn publish(&mut self, description: &MachineDescription) -> Result<(), ShmError> {
        let mut sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| ShmError::iox("loaning the description sample", e))?;
        // SAFETY: the sample's payload is valid for writes of one `MachineDescription` and
        // does not overlap `description` (one lies in the publisher's shared memory, the other
        // is borrowed from the caller); after the copy every byte is initialised. Copying by
        // pointer keeps the 1.3 MB value off the stack.
        let sample = unsafe {
            core::ptr::copy_nonoverlapping(
                description as *const MachineDescription,
                sample.payload_mut().as_mut_ptr(),
                1,
            );
            sample.assume_init()
        };
        sample
            .send()
            .map(|_| ())
            .map_err(|e| ShmError::iox("sending the description", e))
    }

    /// Hands the description to clients that subscribed since the last call (iceoryx2
    /// delivers the history only when the publisher updates its connections).
    pub fn update_connections(&self) -> Result<(), ShmError> {
        use iceoryx2::port::update_connections::UpdateConnections;
        self.publisher
            .update_connections()
            .map_err(|e| ShmError::iox("updating the description's connections", e))
    }
}

type CommandActive = ActiveRequest<ipc::Service, CommandRequest, (), CommandReply, ()>;

/// Receives the commands on `PREFIX/command` (request-response).
pub struct CommandServer {
    server: Server<ipc::Service, CommandRequest, (), CommandReply, ()>,
}

impl core::fmt::Debug for CommandServer {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CommandServer").finish_non_exhaustive()
    }
}

/// Requests a client may have in flight at once.
pub const MAX_ACTIVE_REQUESTS_PER_CLIENT: usize = 4;

impl CommandServer {
    /// Creates (or joins) `names.command`.
    pub fn create(
        node: &Node<ipc::Service>,
        names: &ServiceNames,
        settings: &PublisherSettings,
    ) -> Result<CommandServer, ShmError> {
        let service = node
            .service_builder(&service_name(&names.command)?)
            .request_response::<CommandRequest, CommandReply>()
            .max_servers(1)
            .max_clients(settings.max_clients)
            .max_nodes(settings.max_nodes)
            .max_active_requests_per_client(MAX_ACTIVE_REQUESTS_PER_CLIENT)
            .max_response_buffer_size(MAX_ACTIVE_REQUESTS_PER_CLIENT)
            // A full request queue refuses the client's send (it reports `Overloaded`) rather
            // than dropping a request silently.
            .enable_safe_overflow_for_requests(false)
            .enable_safe_overflow_for_responses(true)
            .open_or_create()
            .map_err(|e| ShmError::iox("opening the command service", e))?;
        let server = service
            .server_builder()
            // Never block the coordinator on a client that does not read its replies.
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(|e| ShmError::iox("creating the command server", e))?;
        Ok(CommandServer { server })
    }

    /// The next request, if any. A failure to receive (a client died mid-request) is skipped.
    pub fn receive(&mut self) -> Option<PendingCommand> {
        match self.server.receive() {
            Ok(Some(active)) => {
                let request = *active.payload();
                Some(PendingCommand {
                    active: Some(active),
                    request,
                })
            }
            Ok(None) | Err(_) => None,
        }
    }
}

/// A received command awaiting its one reply. Dropped without [`PendingCommand::reply`], it
/// answers [`crate::contract::status::OVERLOADED`] itself, so a client never waits for a reply
/// that will not come.
pub struct PendingCommand {
    active: Option<CommandActive>,
    request: CommandRequest,
}

impl core::fmt::Debug for PendingCommand {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("PendingCommand")
            .field("request", &self.request)
            .finish_non_exhaustive()
    }
}

impl PendingCommand {
    /// The request (copied out of shared memory, so a client cannot change it under us).
    pub fn request(&self) -> &CommandRequest {
        &self.request
    }

    /// Sends the reply; the tag is set to the request's. Consumes the command: exactly one
    /// reply per request.
    pub fn reply(mut self, reply: &CommandReply) -> Result<(), ShmError> {
        let mut r = *reply;
        r.tag = self.request.tag;
        match self.active.take() {
            Some(active) => active
                .send_copy(r)
                .map_err(|e| ShmError::iox("sending a command reply", e)),
            None => Ok(()),
        }
    }
}

impl Drop for PendingCommand {
    fn drop(&mut self) {
        if let Some(active) = self.active.take() {
            // Best effort: a client that died meanwhile cannot be answered anyway.
            let _ = active.send_copy(CommandReply::rejected(
                self.request.tag,
                crate::contract::status::OVERLOADED,
                0,
            ));
        }
    }
}

/// A notifier on `names.events`, opening or creating the service. Both of its notifiers (the
/// event publisher's and the cycle thread's [`StateNotifier`]) come from here, so the service is always created
/// with the same settings whichever opens it first.
fn events_notifier(
    node: &Node<ipc::Service>,
    names: &ServiceNames,
    settings: &PublisherSettings,
    step: &'static str,
) -> Result<Notifier<ipc::Service>, ShmError> {
    node.service_builder(&service_name(&names.events)?)
        .event()
        // The event publisher and the cycle thread's state notifier.
        .max_notifiers(2)
        .max_listeners(settings.max_subscribers)
        .max_nodes(settings.max_nodes)
        .event_id_max_value(EVENT_ID_MAX)
        .open_or_create()
        .map_err(|e| ShmError::iox("opening the events service", e))?
        .notifier_builder()
        .create()
        .map_err(|e| ShmError::iox(step, e))
}

/// Publishes [`EventRecord`]s on `PREFIX/event-log` and signals each on `PREFIX/events`.
pub struct EventPublisher {
    publisher: Publisher<ipc::Service, EventRecord, ()>,
    notifier: Notifier<ipc::Service>,
}

impl core::fmt::Debug for EventPublisher {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("EventPublisher").finish_non_exhaustive()
    }
}

/// The highest event id the `events` service carries (ids are [`crate::contract::event_id`]).
pub const EVENT_ID_MAX: usize = 63;

impl EventPublisher {
    /// Creates (or joins) `names.event_log` and `names.events`.
    pub fn create(
        node: &Node<ipc::Service>,
        names: &ServiceNames,
        settings: &PublisherSettings,
    ) -> Result<EventPublisher, ShmError> {
        let log = node
            .service_builder(&service_name(&names.event_log)?)
            .publish_subscribe::<EventRecord>()
            .max_publishers(1)
            .max_subscribers(settings.max_subscribers)
            .max_nodes(settings.max_nodes)
            .history_size(settings.event_history)
            .subscriber_max_buffer_size(settings.event_history.max(1))
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(|e| ShmError::iox("opening the event-log service", e))?;
        let publisher = log
            .publisher_builder()
            .create()
            .map_err(|e| ShmError::iox("creating the event-log publisher", e))?;
        let notifier = events_notifier(node, names, settings, "creating the events notifier")?;
        Ok(EventPublisher {
            publisher,
            notifier,
        })
    }

    /// Publishes `rec` on the log, then signals its id (so a woken listener finds the record).
    pub fn publish(&mut self, rec: EventRecord) -> Result<(), ShmError> {
        self.publisher
            .send_copy(rec)
            .map_err(|e| ShmError::iox("publishing an event record", e))?;
        let id = usize::from(rec.id).min(EVENT_ID_MAX);
        self.notifier
            .notify_with_custom_event_id(EventId::new(id))
            .map_err(|e| ShmError::iox("signalling an event", e))?;
        Ok(())
    }
}

/// Signals [`crate::contract::event_id::STATE_PUBLISHED`] on `PREFIX/events`: what an
/// event-driven client waits on. The coordinator's cycle thread calls [`StateNotifier::notify`]
/// right after sending each state, so a waiting client wakes as soon as the state is out (a
/// relay thread polling for the publication added its own wake-up lateness, 2x the bare pair's
/// latency and worse under load). The notify allocates nothing; it writes the event id into
/// the service's shared memory and wakes each listener (one `write` on each listener's
/// socket), which does not block: a full socket drops the wake-up, never waits.
pub struct StateNotifier {
    notifier: Notifier<ipc::Service>,
}

impl core::fmt::Debug for StateNotifier {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("StateNotifier").finish_non_exhaustive()
    }
}

impl StateNotifier {
    /// Joins (or creates) `names.events`.
    pub fn create(
        node: &Node<ipc::Service>,
        names: &ServiceNames,
        settings: &PublisherSettings,
    ) -> Result<StateNotifier, ShmError> {
        let notifier = events_notifier(node, names, settings, "creating the state notifier")?;
        Ok(StateNotifier { notifier })
    }

    /// Signals that a new state is out. Allocates nothing and never waits (see the type).
    pub fn notify(&self) -> Result<(), ShmError> {
        self.notifier
            .notify_with_custom_event_id(EventId::new(crate::contract::event_id::STATE_PUBLISHED))
            .map(|_| ())
            .map_err(|e| ShmError::iox("notifying a new state", e))
    }
}
