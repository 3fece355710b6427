//! Record and replay: a recording of the embedded machine replays identically, and a recording
//! changed in one frame, one state byte or one input is caught at that cycle with what differs.

use std::path::{Path, PathBuf};

use coordinator::command::{Command, Target};
use coordinator::config::{Config, EXAMPLE};
use coordinator::runtime::plan::plan;
use coordinator::runtime::record::format::CycleRecord;
use coordinator::runtime::record::recorder::write_recording;
use coordinator::runtime::record::replay::{Outcome, Recording, ReplaySummary, replay};
use coordinator::runtime::run::RecordTo;
use coordinator::runtime::synthetic;
use coordinator::runtime::virtual_clock::VirtualRun;

/// Removes the file when the test ends.
struct Scratch(PathBuf);
impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn scratch(name: &str) -> Scratch {
    Scratch(std::env::temp_dir().join(format!("{name}-{}.rec", std::process::id())))
}

/// Records `cycles` cycles of the embedded machine's demonstration, with an override from an
/// in-process client at cycle 1500.
fn record(path: &Path, cycles: u64) {
    let cfg = Config::parse(EXAMPLE).unwrap();
    let plan = plan(&cfg).unwrap();
    let mut opts = synthetic::demo_options(true);
    opts.record = Some(RecordTo {
        path: path.to_path_buf(),
        config: EXAMPLE.to_string(),
    });
    let mut run = VirtualRun::new(&plan, &opts).unwrap();
    let mut out = Vec::new();
    while run.cycles() < cycles {
        if run.cycles() == 1500 {
            run.submit(Command::SetOverride {
                target: Target::All,
                percent: 70,
            })
            .unwrap();
        }
        run.step(&mut out);
    }
    let s = run.finish(std::time::Duration::ZERO);
    let line = s.recording.unwrap();
    assert!(line.contains(&format!("{cycles} cycles")), "{line}");
}

fn replayed(path: &Path) -> ReplaySummary {
    let mut out = Vec::new();
    let s = replay(path, &mut out).unwrap();
    assert!(String::from_utf8_lossy(&out).starts_with("replaying "));
    s
}

/// The recording of `path` changed by `change` into `to`.
fn changed(path: &Path, to: &Path, change: impl FnOnce(&mut Vec<(CycleRecord, Vec<u8>)>)) {
    let r = Recording::open(path).unwrap();
    let mut cycles = r.cycles().unwrap();
    change(&mut cycles);
    write_recording(to, &r.header, &cycles).unwrap();
}

#[test]
fn the_demo_replays_identically_and_each_change_is_found_at_its_cycle() {
    let rec = scratch("replay-demo");
    record(&rec.0, 3000);
    let s = replayed(&rec.0);
    assert_eq!(s.outcome, Outcome::Identical, "{s}");
    assert_eq!(s.cycles, 3000);
    assert_eq!(s.states, 3000);
    assert_eq!(s.commands, 1, "{s}");
    assert!(s.frames > 10_000, "{s}");
    assert!(!s.cut);

    // A frame the cycle sent, one bit changed in the recording.
    let t = scratch("replay-frame");
    let mut at = (0, 0, String::new());
    changed(&rec.0, &t.0, |c| {
        let (k, (r, _)) = c
            .iter_mut()
            .enumerate()
            .skip(2000)
            .find(|(_, (r, _))| r.sent.iter().any(|(f, _)| f.frame.dlc() > 0))
            .unwrap();
        let i = r.sent.iter().position(|(f, _)| f.frame.dlc() > 0).unwrap();
        r.sent[i].0.frame.data_mut()[0] ^= 0x01;
        at = (k, i + 1, String::new());
    });
    let s = replayed(&t.0);
    match &s.outcome {
        Outcome::Diverged { cycle, what } => {
            assert_eq!(*cycle, at.0 as u64, "{s}");
            assert!(
                what.starts_with(&format!("frame {} sent: expected bus ", at.1)),
                "{s}"
            );
            assert!(what.contains(", found bus "), "{s}");
        }
        o => panic!("not found: {o:?}"),
    }

    // One byte of a published state: axis 0's position.
    let t = scratch("replay-state");
    changed(&rec.0, &t.0, |c| {
        let axes = std::mem::offset_of!(shm_api::contract::MachineState, axes);
        let pos = std::mem::offset_of!(shm_api::contract::AxisState, position);
        c[2500].1[axes + pos] ^= 0x10;
    });
    let s = replayed(&t.0);
    match &s.outcome {
        Outcome::Diverged { cycle, what } => {
            assert_eq!(*cycle, 2500, "{s}");
            assert!(
                what.starts_with("state field axes[0].position: expected "),
                "{s}"
            );
        }
        o => panic!("not found: {o:?}"),
    }

    // An input: the client's override asked for another value. The cycle answers the same, but
    // what it does (its state, then its frames) differs from that cycle on.
    let t = scratch("replay-input");
    changed(&rec.0, &t.0, |c| {
        let r = &mut c[1500].0;
        assert_eq!(r.requests.len(), 1);
        r.requests[0].command = Command::SetOverride {
            target: Target::All,
            percent: 20,
        };
    });
    let s = replayed(&t.0);
    match &s.outcome {
        Outcome::Diverged { cycle, .. } => assert_eq!(*cycle, 1500, "{s}"),
        o => panic!("not found: {o:?}"),
    }

    // A run killed mid-recording: the file ends inside its stream.
    let t = scratch("replay-cut");
    let bytes = std::fs::read(&rec.0).unwrap();
    std::fs::write(&t.0, &bytes[..bytes.len() * 3 / 5]).unwrap();
    let s = replayed(&t.0);
    assert_eq!(s.outcome, Outcome::Identical, "{s}");
    assert!(s.cut);
    assert!(s.cycles > 1000 && s.cycles < 3000, "{s}");
    assert!(s.to_string().contains("ends early"), "{s}");
}
