//! `drive-sim --write-eds DEVICE`: each simulated CANopen device's EDS, read back by our own
//! EDS parser, is the simulator's dictionary: every entry with its name, type, access, PDO mapping,
//! limits and value, at the node the file was made for and at another (COB-IDs follow
//! `$NODEID`). The Python test (`python_can.rs`) has python-canopen import the same files.

use std::process::Command;

use drivers::canopen::eds::Eds;
use drivers::canopen::od::{DataType, EntryDef, ObjectDictionary, TypeClass, encode_value};
use drivers::canopen::{Address, NodeId};
use drivers::sim::emca::Emca;
use drivers::sim::mtr_dci::{MtrDci, Profile as MtrProfile};
use drivers::sim::tlc5xx::{Tlc5xx, TlcConfig};
use drivers::time::Instant;
use integration_tests::workspace_bin;

fn eds(args: &[&str]) -> (Option<i32>, String, String) {
    let out = Command::new(workspace_bin("coordinator", "drive-sim"))
        .args(args)
        .output()
        .expect("drive-sim runs");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A value's bytes as the file gives them, for comparison with the dictionary's: strings up to
/// their first NUL and without trailing blanks (an INI value cannot end in one).
fn comparable(dt: DataType, raw: &[u8]) -> Vec<u8> {
    if dt == DataType::VisibleString {
        let end = raw.iter().position(|&b| b == 0).unwrap_or(raw.len());
        let mut v = raw[..end].to_vec();
        while v.last() == Some(&b' ') {
            v.pop();
        }
        v
    } else {
        raw.to_vec()
    }
}

/// Every entry of `od` is in `file` as it is in the dictionary, and the file has no other.
fn same<const N: usize, const B: usize>(what: &str, od: &ObjectDictionary<'_, N, B>, file: &Eds) {
    let defs: Vec<EntryDef<'_>> = file.entry_defs();
    assert_eq!(
        defs.len(),
        od.len(),
        "{what}: entries in the file and the dictionary"
    );
    for e in od.entries() {
        let f = file
            .entry(e.addr)
            .unwrap_or_else(|| panic!("{what}: {} is not in the file", e.addr))
            .to_def();
        assert_eq!(
            (f.name, f.data_type, f.access, f.pdo_mappable),
            (e.name, e.data_type, e.access, e.pdo_mappable),
            "{what}: {}",
            e.addr
        );
        if !matches!(e.data_type.class(), TypeClass::Bytes) {
            assert_eq!(
                (f.low, f.high),
                (e.low, e.high),
                "{what}: {} limits",
                e.addr
            );
        }
        let raw = od.raw(e.addr).expect("a dictionary entry has a value");
        let mut buf = vec![0u8; 8.max(raw.len()).max(64)];
        let n = encode_value(f.data_type, &f.default, &mut buf)
            .unwrap_or_else(|c| panic!("{what}: {} default does not encode: {c}", e.addr));
        assert_eq!(
            comparable(e.data_type, &buf[..n]),
            comparable(e.data_type, raw),
            "{what}: {} value",
            e.addr
        );
    }
}

#[test]
fn each_simulated_device_s_eds_reads_back_into_its_dictionary_at_any_node() {
    for node in [1u8, 5] {
        let id = NodeId::new(node).unwrap();
        let t0 = Instant::ZERO;
        let tlc = Tlc5xx::new(TlcConfig::new(id), t0).unwrap();
        let mtr = MtrDci::new(id, MtrProfile::Fhpp, t0).unwrap();
        let mtr402 = MtrDci::new(id, MtrProfile::Cia402, t0).unwrap();
        let emca = Emca::new(id, t0).unwrap();
        let cases: [(&[&str], &str); 4] = [
            (&["--write-eds", "tlc5xx"], "tlc5xx"),
            (&["--write-eds", "mtr-dci"], "mtr-dci"),
            (
                &["--write-eds", "mtr-dci", "--profile", "cia402"],
                "mtr-dci cia402",
            ),
            (&["--write-eds", "emca"], "emca"),
        ];
        for (args, what) in cases {
            let (code, text, err) = eds(args);
            assert_eq!(code, Some(0), "{what}: {err}");
            assert!(text.starts_with("[FileInfo]\n"), "{what}: {text}");
            let file = Eds::parse(&text, Some(id))
                .unwrap_or_else(|e| panic!("{what}: our parser refuses it: {e}\n{text}"));
            let what = format!("{what} at node {node}");
            match *args {
                [_, "tlc5xx"] => same(&what, tlc.od(), &file),
                [_, "mtr-dci"] => same(&what, mtr.device().od(), &file),
                [_, "mtr-dci", ..] => same(&what, mtr402.device().od(), &file),
                _ => same(&what, emca.device().od(), &file),
            }
            // The identity the coordinator checks at boot is the file's too.
            let vendor = file
                .entry(Address::new(0x1018, 1))
                .unwrap()
                .to_def()
                .default;
            assert!(
                text.contains(&format!(
                    "VendorNumber=0x{:X}",
                    match vendor {
                        drivers::canopen::od::Value::Unsigned(v) => v,
                        other => panic!("{what}: 1018h:01 is {other:?}"),
                    }
                )),
                "{what}"
            );
        }
    }
}

#[test]
fn a_modbus_device_has_no_eds_and_says_so() {
    let (code, text, err) = eds(&["--write-eds", "cmmo-st"]);
    assert_eq!(code, Some(1), "{text}{err}");
    assert!(text.is_empty());
    assert!(
        err.contains(
            "--write-eds cmmo-st: the CMMO-ST speaks Modbus TCP, not CANopen; it has no EDS"
        ),
        "{err}"
    );
    let (code, _, err) = eds(&["--write-eds", "tlc5xx", "--profile", "fhpp"]);
    assert_eq!(code, Some(1));
    assert!(
        err.contains("--profile fhpp: the TLC5xx offers CiA 402 only"),
        "{err}"
    );
}
