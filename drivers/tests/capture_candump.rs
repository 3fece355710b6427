//! candump log files: what the writer produces, the reader gives back exactly.
#![cfg(feature = "std")]

use drivers::can::Frame;
use drivers::can::candump::{CandumpError, CandumpWriter, read_log};
use drivers::time::Instant;
use proptest::prelude::*;

fn arb_frame() -> impl Strategy<Value = Frame> {
    let data = proptest::collection::vec(any::<u8>(), 0..=8);
    prop_oneof![
        (0u16..0x800, data.clone()).prop_map(|(id, d)| Frame::new_std(id, &d).unwrap()),
        (0u32..0x2000_0000, data).prop_map(|(id, d)| Frame::new_ext(id, &d).unwrap()),
        (0u16..0x800, 0u8..=8).prop_map(|(id, n)| Frame::new_std_remote(id, n).unwrap()),
    ]
}

proptest! {
    #[test]
    fn log_round_trip(frames in proptest::collection::vec((arb_frame(), 0u64..4_000_000_000_000_000), 0..40)) {
        let mut w = CandumpWriter::new(Vec::new());
        for (f, us) in &frames {
            w.write(Instant::from_micros(*us), "vbus:x", f).unwrap();
        }
        let bytes = w.into_inner();
        let back = read_log(&bytes[..]).unwrap();
        prop_assert_eq!(back.len(), frames.len());
        for (r, (f, us)) in back.iter().zip(&frames) {
            prop_assert_eq!(&r.frame, f);
            prop_assert_eq!(r.timestamp, Instant::from_micros(*us));
            prop_assert_eq!(r.frame.timestamp(), Instant::from_micros(*us));
            prop_assert_eq!(r.interface.as_str(), "vbus:x");
        }
    }

    #[test]
    fn reader_never_panics(text in "\\PC{0,200}") {
        let _ = read_log(text.as_bytes());
    }
}

#[test]
fn reads_candump_l_output_and_reports_line_numbers() {
    // As `candump -l can0` writes it (one extended and one remote frame included).
    let text = "(1700000000.123456) can0 605#4000100000000000\n\
                \n\
                (1700000000.123789) can0 1F334455#1122\n\
                (1700000000.200000) can0 705#R\n";
    let recs = read_log(text.as_bytes()).unwrap();
    assert_eq!(recs.len(), 3);
    assert_eq!(
        recs[0].timestamp,
        Instant::from_micros(1_700_000_000_123_456)
    );
    assert_eq!(
        recs[1].frame,
        Frame::new_ext(0x1F33_4455, &[0x11, 0x22]).unwrap()
    );
    assert!(recs[2].frame.is_remote());

    let bad = "(1.000000) can0 123#00\n(2.000000) can0 123#0\n";
    match read_log(bad.as_bytes()) {
        Err(e @ CandumpError::Frame { line: 2, .. }) => assert!(e.to_string().contains("line 2")),
        other => panic!("expected a line-2 frame error, got {other:?}"),
    }
}

/// python-can reads our logs and we read its logs (it appends a direction flag, ` R`).
#[test]
fn python_can_interoperates() {
    let have = std::process::Command::new("python3")
        .args(["-c", "import can"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !have {
        // CI (.ci/run) installs python-can and makes this test mandatory.
        assert!(
            std::env::var("MOTION_REQUIRE_ALL").as_deref() != Ok("1"),
            "python-can is not installed and MOTION_REQUIRE_ALL=1"
        );
        {
            use std::io::Write as _;
            let _ = writeln!(
                std::io::stderr(),
                "SKIPPED python_can_interoperates: python3 with python-can is not installed (.ci/run installs it)"
            );
        }
        return;
    }
    let dir = std::env::temp_dir();
    let ours = dir.join(format!("candump_ours_{}.log", std::process::id()));
    let theirs = dir.join(format!("candump_theirs_{}.log", std::process::id()));
    let frames: Vec<Frame> = ["605#4000100000000000", "12345678#DEAD", "705#R", "080#"]
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
    let mut w = CandumpWriter::new(Vec::new());
    for (i, f) in frames.iter().enumerate() {
        w.write(
            Instant::from_micros(1_700_000_000_000_000 + i as u64 * 1_500),
            "vbus:p",
            f,
        )
        .unwrap();
    }
    std::fs::write(&ours, w.into_inner()).unwrap();
    // python-can reads our file and writes every message back in its own words.
    let script = "import can, sys\n\
                  w = can.CanutilsLogWriter(sys.argv[2], channel='vbus:p')\n\
                  for m in can.CanutilsLogReader(sys.argv[1]):\n    \
                  print(hex(m.arbitration_id), m.is_extended_id, m.is_remote_frame, m.data.hex())\n    \
                  w.on_message_received(m)\n\
                  w.stop()\n";
    let out = std::process::Command::new("python3")
        .args(["-c", script])
        .arg(&ours)
        .arg(&theirs)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let seen = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        seen.lines().collect::<Vec<_>>(),
        [
            "0x605 False False 4000100000000000",
            "0x12345678 True False dead",
            "0x705 False True ",
            "0x80 False False "
        ]
    );
    let back = read_log(std::io::BufReader::new(
        std::fs::File::open(&theirs).unwrap(),
    ))
    .unwrap();
    let _ = std::fs::remove_file(&ours);
    let _ = std::fs::remove_file(&theirs);
    assert_eq!(back.iter().map(|r| r.frame).collect::<Vec<_>>(), frames);
    assert_eq!(
        back[1].timestamp,
        Instant::from_micros(1_700_000_000_001_500)
    );
}
