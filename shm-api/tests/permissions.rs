//! What iceoryx2 0.10 does with access rights (see the crate docs, "Access rights"): every
//! shared-memory segment of a service is owner-only; only iceoryx2's global management
//! segment is world-readable and -writable.

use shm_api::{Client, PublisherSettings, ServiceNames, StatePublisher, create_node};
use std::os::unix::fs::PermissionsExt;

#[test]
fn service_segments_are_owner_only() {
    let p = format!("test-{}-{}", "perms", std::process::id());
    let node = create_node().expect("node");
    let names = ServiceNames::new(&p);
    let settings = PublisherSettings::default();
    let _server = shm_api::CommandServer::create(&node, &names, &settings).expect("server");
    let _events = shm_api::EventPublisher::create(&node, &names, &settings).expect("events");
    let mut publisher = StatePublisher::create(&node, &names, &settings).expect("publisher");
    publisher.loan().expect("loan").send().expect("send");
    let mut client = Client::connect(&p).expect("client");
    // The publisher delivers its history to a new subscriber on its next send.
    publisher.loan().expect("loan").send().expect("send");
    assert!(client.latest().is_some());

    let mut segments = 0;
    for entry in std::fs::read_dir("/dev/shm").expect("/dev/shm") {
        let entry = entry.expect("entry");
        let name = entry.file_name().to_string_lossy().into_owned();
        if !name.starts_with("iox2_") || name.ends_with(".global_mgmt") {
            continue;
        }
        // Another test's segment may vanish while we look.
        let Ok(meta) = entry.metadata() else { continue };
        let mode = meta.permissions().mode() & 0o777;
        assert_eq!(mode & 0o077, 0, "{name} has mode {mode:o}");
        segments += 1;
    }
    assert!(segments >= 4, "only {segments} iceoryx2 segments found");
}
