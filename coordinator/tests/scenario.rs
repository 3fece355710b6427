//! Fault campaigns: every kind of fault once on a small machine breaks no invariant, loses no
//! command, and the machine comes back; the same seed gives the same campaign, bit for bit;
//! a scenario that names what the machine does not have is refused in words.

use std::path::{Path, PathBuf};

use coordinator::runtime::scenario::faults::FaultKind;
use coordinator::runtime::scenario::file::ScenarioFile;
use coordinator::runtime::scenario::{Report, ScenarioOptions, run_scenario};

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data")
}

fn each_fault() -> ScenarioFile {
    let text = std::fs::read_to_string(data().join("each-fault.toml")).unwrap();
    ScenarioFile::parse(&text).unwrap()
}

fn run(s: &ScenarioFile, opts: &ScenarioOptions) -> (Report, String) {
    let mut out = Vec::new();
    let r = run_scenario(s, &data(), opts, &mut out).unwrap();
    (r, String::from_utf8_lossy(&out).into_owned())
}

/// Removes the file when the test ends.
struct Scratch(PathBuf);
impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

#[test]
fn every_kind_of_fault_once_breaks_no_invariant_and_the_machine_comes_back() {
    let s = each_fault();
    let (r, progress) = run(&s, &ScenarioOptions::default());
    assert!(r.violation.is_none(), "{r}");
    for k in FaultKind::ALL {
        assert_eq!(r.injected.get(&k), Some(&1), "{}: {r}", k.name());
    }
    assert_eq!(r.books.lost, 0, "{r}");
    assert_eq!(r.books.doubled, 0, "{r}");
    // The flood was more than the inbox takes: refused at the door, not lost.
    assert!(r.books.refused_at_door > 0, "{r}");
    // The faults did fault axes, and the operator brought them back.
    assert!(r.books.recovery > 0, "{r}");
    assert!(r.recovered_after.is_some(), "{r}");
    assert!(progress.contains("scenario:  50 %"), "{progress}");
    let text = r.to_string();
    assert!(text.contains("invariant violations: 0"), "{text}");
    assert!(!text.contains("Some("), "{text}");
}

#[test]
fn the_same_seed_gives_the_same_campaign_and_another_seed_another() {
    let mut s = each_fault();
    s.faults.clear();
    s.random = Some(coordinator::runtime::scenario::file::RandomFaults {
        every_s: 0.5,
        length_s: [0.02, 0.3],
        kinds: Vec::new(),
    });
    let a = Scratch(std::env::temp_dir().join(format!("scn-a-{}.rec", std::process::id())));
    let b = Scratch(std::env::temp_dir().join(format!("scn-b-{}.rec", std::process::id())));
    let opts = |p: &Path, seed| ScenarioOptions {
        seed: Some(seed),
        record: Some(p.to_path_buf()),
        quiet: true,
        ..ScenarioOptions::default()
    };
    let (ra, _) = run(&s, &opts(&a.0, 5));
    let (rb, _) = run(&s, &opts(&b.0, 5));
    assert!(ra.violation.is_none(), "{ra}");
    assert!(ra.faults() > 5, "{ra}");
    assert_eq!(ra.injected, rb.injected);
    assert_eq!(ra.cycles, rb.cycles);
    assert_eq!(std::fs::read(&a.0).unwrap(), std::fs::read(&b.0).unwrap());
    let (rc, _) = run(&s, &opts(&b.0, 6));
    assert!(rc.violation.is_none(), "{rc}");
    assert_ne!(
        (ra.injected, ra.cycles),
        (rc.injected, rc.cycles),
        "seed 6 drew the same campaign as seed 5"
    );
    // The campaign's recording replays bit for bit.
    let mut out = Vec::new();
    let rep = coordinator::runtime::record::replay::replay(&a.0, &mut out).unwrap();
    assert_eq!(
        rep.outcome,
        coordinator::runtime::record::replay::Outcome::Identical,
        "{rep}"
    );
}

#[test]
fn a_scenario_naming_what_the_machine_lacks_is_refused_in_words() {
    let mut s = each_fault();
    s.faults[4].axis = Some("z9".into());
    let mut out = Vec::new();
    let e = run_scenario(&s, &data(), &ScenarioOptions::default(), &mut out).unwrap_err();
    assert_eq!(e, "fault[4].axis = \"z9\": no such axis");
    let mut s = each_fault();
    s.faults[11].axis = Some("a0".into());
    let e = run_scenario(&s, &data(), &ScenarioOptions::default(), &mut out).unwrap_err();
    assert_eq!(
        e,
        "fault[11].axis = \"a0\": a modbus-drop needs an axis on Modbus"
    );
    let mut s = each_fault();
    s.machine = "no-such-machine.toml".into();
    s.synthetic = None;
    let e = run_scenario(&s, &data(), &ScenarioOptions::default(), &mut out).unwrap_err();
    assert!(
        e.starts_with("machine = \"no-such-machine.toml\": cannot read "),
        "{e}"
    );
}

#[test]
fn sync_consumer_mode_survives_lost_and_late_syncs() {
    let text = std::fs::read_to_string(data().join("consumer-sync.toml")).unwrap();
    let s = ScenarioFile::parse(&text).unwrap();
    let opts = ScenarioOptions {
        duration_s: Some(20.0),
        quiet: true,
        ..ScenarioOptions::default()
    };
    let (r, _) = run(&s, &opts);
    assert!(r.violation.is_none(), "{r}");
    assert!(
        r.injected
            .get(&FaultKind::SyncLoss)
            .is_some_and(|&n| n >= 2),
        "{r}"
    );
    assert!(
        r.injected
            .get(&FaultKind::SyncLate)
            .is_some_and(|&n| n >= 1),
        "{r}"
    );
    assert_eq!(r.books.lost, 0, "{r}");
    assert!(r.recovered_after.is_some(), "{r}");
}
