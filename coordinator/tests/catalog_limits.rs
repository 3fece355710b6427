//! `coordinator check` and `coordinator run` agree at every limit of every device kind: each
//! configuration below sits on one side of one limit of `drivers::catalog` (a profile offered or
//! not, the FPC, heartbeat and guarding, node-IDs, record numbers and chaining) or of the
//! machine (axes, groups, group size, buses). One that `Config::check` accepts must plan, build
//! a virtual-time run and boot every drive without a boot failure or a fault; one it refuses
//! must name the key. And the limits table in docs/configuration.md is the catalog's.

use std::fmt::Write as _;

use coordinator::config::{Config, MAX_AXES, MAX_BUSES, MAX_GROUPS, MAX_HEARTBEAT_MS};
use coordinator::records::MAX_GROUP_AXES;
use coordinator::runtime::plan::plan;
use coordinator::runtime::run::RunOptions;
use coordinator::runtime::script::ScriptOptions;
use coordinator::runtime::virtual_clock::VirtualRun;
use drivers::catalog::{self, DEVICES, Device, Link, Profile};

/// The cycle of every machine here, µs.
const CYCLE_US: u32 = 2000;
/// Cycles a drive may take to boot before the test gives up (a node boots in about 50).
const BOOT_CYCLES: usize = 400;
/// Cycles run after the boot, long enough for a supervision that cannot hold to fail.
const AFTER_BOOT: usize = 25;

fn options() -> RunOptions {
    RunOptions {
        virtual_time: true,
        shm: None,
        duration: None,
        status_every: None,
        script: ScriptOptions {
            demo: true,
            chains: false,
            home: true,
        },
        capture: None,
        record: None,
    }
}

/// One `[[axes]]` table named `name`: a CANopen axis on bus `can{bus}` at `node`, or a simulated
/// Modbus axis; `extra` lines go in as they are.
fn axis(name: &str, d: &Device, bus: usize, node: i64, extra: &str) -> String {
    let place = match d.link {
        Link::Canopen => format!("bus = \"can{bus}\"\nnode = {node}"),
        Link::ModbusTcp => "simulated = true".to_string(),
    };
    format!(
        "\n[[axes]]\nname = \"{name}\"\ndevice = \"{}\"\n{place}\n{extra}\nincrements_per_unit = 1000.0\nlimits = {{ position_min = 0.0, position_max = 100.0, velocity = 50.0, acceleration = 500.0 }}\n",
        d.id
    )
}

/// A machine of `buses` simulated buses and the given tables.
fn machine(buses: usize, tables: &str) -> String {
    machine_with(CYCLE_US, buses, tables)
}

/// As [`machine`] with a cycle of `cycle_us`.
fn machine_with(cycle_us: u32, buses: usize, tables: &str) -> String {
    let mut s = format!("cycle_us = {cycle_us}\n");
    for b in 0..buses {
        let _ = write!(s, "\n[[buses]]\nname = \"can{b}\"\nkind = \"simulated\"\n");
    }
    s + tables
}

/// A machine with one axis `a` of `d`.
fn one(d: &Device, extra: &str) -> String {
    machine(1, &axis("a", d, 0, 1, extra))
}

/// A record table of axis `a`.
fn record(number: i64, next: Option<i64>) -> String {
    let next = next.map_or(String::new(), |n| format!("next = {n}\n"));
    format!(
        "\n[[records]]\naxis = \"a\"\nnumber = {number}\nposition = 1.0\nvelocity = 10.0\n{next}"
    )
}

/// What `check` should say: accept, or refuse naming `key` (and `value` in the message).
#[derive(Debug)]
enum Expect {
    Accept,
    Refuse { key: String, value: Option<String> },
}

fn refuse(key: &str) -> Expect {
    Expect::Refuse {
        key: key.into(),
        value: None,
    }
}

fn refuse_value(key: &str, value: impl ToString) -> Expect {
    Expect::Refuse {
        key: key.into(),
        value: Some(value.to_string()),
    }
}

fn accept_if(ok: bool, key: &str) -> Expect {
    if ok { Expect::Accept } else { refuse(key) }
}

/// Checks one configuration both ways: `check`'s verdict is the expected one, and `run` agrees.
fn agree(label: &str, text: &str, expect: Expect) {
    let cfg = Config::parse(text).unwrap_or_else(|e| panic!("{label}: {e}\n{text}"));
    let report = cfg.check();
    match expect {
        Expect::Refuse { key, value } => {
            let named = report.errors.iter().find(|e| e.key == key);
            assert!(
                named.is_some(),
                "{label}: expected a refusal of {key}, got:\n{report}\n{text}"
            );
            if let (Some(v), Some(e)) = (value, named) {
                assert!(e.to_string().contains(&v), "{label}: {e} does not name {v}");
            }
            assert!(plan(&cfg).is_err(), "{label}: planned what check refused");
        }
        Expect::Accept => {
            assert!(report.is_ok(), "{label}: refused\n{report}\n{text}");
            let p = plan(&cfg).unwrap_or_else(|e| panic!("{label}: check accepted, plan: {e}"));
            let mut run = VirtualRun::new(&p, &options())
                .unwrap_or_else(|e| panic!("{label}: check accepted, run: {e}"));
            let mut out = Vec::new();
            let mut cycles = 0;
            while !run.booted() && cycles < BOOT_CYCLES {
                run.step(&mut out);
                cycles += 1;
            }
            for _ in 0..AFTER_BOOT {
                run.step(&mut out);
            }
            let log = String::from_utf8_lossy(&out);
            assert!(
                run.booted(),
                "{label}: not booted in {cycles} cycles\n{log}"
            );
            let s = &run.io.summary;
            assert!(
                s.boot_failures.is_empty() && s.faults.is_empty(),
                "{label}: boot failures {:?}, faults {:?}\n{log}\n{text}",
                s.boot_failures,
                s.faults
            );
        }
    }
}

#[test]
fn profiles_and_the_fpc() {
    for d in DEVICES {
        for p in [Profile::Fhpp, Profile::Cia402] {
            let extra = format!("profile = \"{}\"", p.id());
            let label = format!("{} {}", d.id, p.id());
            agree(
                &label,
                &one(d, &extra),
                accept_if(d.offers(p), "axes[0].profile"),
            );
            // The FPC where the profile has it on PDO2, refused elsewhere.
            if let Some(facts) = d.profile(p) {
                let fpc = format!("{extra}\nfpc = true");
                let ok = facts.fpc_pdo2.is_some();
                agree(
                    &format!("{label} fpc"),
                    &one(d, &fpc),
                    accept_if(ok, "axes[0].fpc"),
                );
            }
        }
        // The default profile is the catalog's first.
        agree(d.id, &one(d, ""), Expect::Accept);
    }
}

#[test]
fn heartbeat_and_guarding() {
    let cycle_ms = i64::from(CYCLE_US / 1000);
    for d in DEVICES {
        if d.link == Link::ModbusTcp {
            // Supervised by its Modbus timeout: neither key is taken.
            agree(
                d.id,
                &one(d, "heartbeat_ms = 100"),
                refuse("axes[0].heartbeat_ms"),
            );
            agree(
                d.id,
                &one(d, "guard_time_ms = 100"),
                refuse("axes[0].guard_time_ms"),
            );
            continue;
        }
        let both = "heartbeat_ms = 100\nguard_time_ms = 100";
        agree(d.id, &one(d, both), refuse("axes[0].heartbeat_ms"));
        match d.heartbeat_max_ms {
            None => {
                let e = refuse("axes[0].heartbeat_ms");
                agree(
                    &format!("{} heartbeat", d.id),
                    &one(d, "heartbeat_ms = 100"),
                    e,
                );
            }
            Some(max) => {
                let max = i64::from(max).min(MAX_HEARTBEAT_MS.into());
                for v in [0, 1, 100, max] {
                    let text = one(d, &format!("heartbeat_ms = {v}"));
                    agree(&format!("{} heartbeat {v}", d.id), &text, Expect::Accept);
                }
                let text = one(d, &format!("heartbeat_ms = {}", max + 1));
                let e = refuse_value("axes[0].heartbeat_ms", max + 1);
                agree(&format!("{} heartbeat {}", d.id, max + 1), &text, e);
            }
        }
        let max = i64::from(d.guard_time_max_ms.expect("CANopen drives guard"));
        // 0 disables; below the cycle the drive's life time would run out between two polls.
        for (v, ok) in [
            (0, true),
            (cycle_ms - 1, false),
            (cycle_ms, true),
            (max, true),
        ] {
            let text = one(d, &format!("guard_time_ms = {v}"));
            let e = if ok {
                Expect::Accept
            } else {
                refuse_value("axes[0].guard_time_ms", v)
            };
            agree(&format!("{} guard {v}", d.id), &text, e);
        }
        let e = refuse_value("axes[0].guard_time_ms", max + 1);
        let text = one(d, &format!("guard_time_ms = {}", max + 1));
        agree(&format!("{} guard {}", d.id, max + 1), &text, e);
    }
}

#[test]
fn node_ids() {
    let ids = catalog::NODE_IDS;
    let (first, last) = (i64::from(*ids.start()), i64::from(*ids.end()));
    for d in DEVICES {
        for node in [first - 1, first, last, last + 1] {
            let label = format!("{} node {node}", d.id);
            let text = match d.link {
                Link::Canopen => machine(1, &axis("a", d, 0, node, "")),
                // A Modbus drive has an address, never a node-ID.
                Link::ModbusTcp => one(d, &format!("node = {node}")),
            };
            let ok = d.link == Link::Canopen && (first..=last).contains(&node);
            let e = if ok {
                Expect::Accept
            } else {
                refuse("axes[0].node")
            };
            agree(&label, &text, e);
        }
    }
    // Two drives on one node of one bus, and the same node on two buses.
    let tlc = &catalog::TLC5XX;
    let twice = axis("a", tlc, 0, 5, "") + &axis("b", tlc, 0, 5, "");
    agree("node twice", &machine(1, &twice), refuse("axes[1].node"));
    let apart = axis("a", tlc, 0, 5, "") + &axis("b", tlc, 1, 5, "");
    agree("node on two buses", &machine(2, &apart), Expect::Accept);
}

#[test]
fn drive_record_tables() {
    for d in DEVICES {
        let Some(table) = d.records else {
            // No table of its own: any record is refused at its axis.
            agree(
                d.id,
                &(one(d, "") + &record(1, None)),
                refuse("records[0].axis"),
            );
            continue;
        };
        let last = i64::from(table.last);
        for (n, ok) in [(0, false), (1, true), (last, true), (last + 1, false)] {
            let text = one(d, "") + &record(n, None);
            let e = if ok {
                Expect::Accept
            } else {
                refuse_value("records[0].number", n)
            };
            agree(&format!("{} record {n}", d.id), &text, e);
        }
        // `next` only where the drive chains records itself.
        let chained = one(d, "") + &record(1, Some(last)) + &record(last, None);
        let e = accept_if(table.chaining, "records[0].next");
        agree(&format!("{} chain", d.id), &chained, e);
    }
}

/// Axes spread over every bus: the CANopen drives first (one per bus, each kind in turn), the
/// rest simulated CMMO-STs, which need no boot and keep the test fast.
fn many_axes(axes: usize, buses: usize) -> String {
    let canopen: Vec<&Device> = DEVICES.iter().copied().filter(|d| d.is_canopen()).collect();
    let mut tables = String::new();
    for i in 0..axes {
        let (d, bus) = if i < buses {
            (canopen[i % canopen.len()], i)
        } else {
            (&catalog::CMMO_ST, 0)
        };
        tables += &axis(&format!("a{i}"), d, bus, 1, "");
    }
    machine(buses, &tables)
}

#[test]
fn buses_and_axes_at_the_maximum() {
    agree("buses", &many_axes(MAX_BUSES, MAX_BUSES), Expect::Accept);
    let e = refuse_value("buses", MAX_BUSES + 1);
    agree("buses + 1", &many_axes(MAX_BUSES + 1, MAX_BUSES + 1), e);
    agree("axes", &many_axes(MAX_AXES, MAX_BUSES), Expect::Accept);
    let e = refuse_value("axes", MAX_AXES + 1);
    agree("axes + 1", &many_axes(MAX_AXES + 1, MAX_BUSES), e);
}

#[test]
fn groups_at_the_maximum() {
    // Every group one Modbus axis.
    let groups = |n: usize| {
        let mut tables = String::new();
        for g in 0..n {
            tables += &axis(&format!("a{g}"), &catalog::CMMO_ST, 0, 0, "");
            let _ = write!(tables, "\n[[groups]]\nname = \"g{g}\"\naxes = [\"a{g}\"]\n");
        }
        machine(0, &tables)
    };
    agree("groups", &groups(MAX_GROUPS), Expect::Accept);
    let e = refuse_value("groups", MAX_GROUPS + 1);
    agree("groups + 1", &groups(MAX_GROUPS + 1), e);
    // One group of as many TLC5xx as the cycle moves together, and one more, on a cycle long
    // enough for their PDOs.
    let sized = |n: usize| {
        let mut tables = String::new();
        let mut names = Vec::new();
        for i in 0..n {
            tables += &axis(&format!("a{i}"), &catalog::TLC5XX, 0, i as i64 + 1, "");
            names.push(format!("\"a{i}\""));
        }
        let _ = write!(
            tables,
            "\n[[groups]]\nname = \"g\"\naxes = [{}]\n",
            names.join(", ")
        );
        machine_with(10_000, 1, &tables)
    };
    agree("group size", &sized(MAX_GROUP_AXES), Expect::Accept);
    let e = refuse_value("groups[0].axes", MAX_GROUP_AXES + 1);
    agree("group size + 1", &sized(MAX_GROUP_AXES + 1), e);
}

/// The limits table of docs/configuration.md, row by row, as the catalog has it.
fn limits_table() -> String {
    let mut s = String::from(
        "| `device` | drive | link | `profile` (first = default) | 1000h | 1018h:01 | PDO1, each way | `fpc` | `heartbeat_ms` | `guard_time_ms` | `[[records]]` `number` | `next` |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let per_profile = |d: &Device, f: &dyn Fn(&catalog::ProfileFacts) -> Option<String>| {
        let v: Vec<String> = d
            .profiles
            .iter()
            .filter_map(|p| {
                f(p).map(|x| match d.profiles.len() {
                    1 => x,
                    _ => format!("{x} ({})", p.profile.id()),
                })
            })
            .collect();
        if v.is_empty() {
            "—".to_string()
        } else {
            v.join(", ")
        }
    };
    for d in DEVICES {
        let profiles: Vec<&str> = d.profiles.iter().map(|p| p.profile.id()).collect();
        let device_type = per_profile(d, &|p| p.device_type.map(|t| format!("{t:08X}h")));
        let vendor = d.vendor_id.map_or("—".into(), |v| format!("{v:08X}h"));
        let pdo1 = match d.link {
            Link::ModbusTcp => "— (Modbus registers)".to_string(),
            Link::Canopen => per_profile(d, &|p| {
                let pdo = p.pdo1?;
                let how = if p.pdo1_static {
                    "static"
                } else {
                    "mapped at boot"
                };
                Some(format!("{} bytes {how}", pdo.rpdo_bytes()))
            }),
        };
        let fpc: Vec<&str> = d
            .profiles
            .iter()
            .filter(|p| p.fpc_pdo2.is_some())
            .map(|p| p.profile.id())
            .collect();
        let fpc = if fpc.is_empty() {
            "refused".to_string()
        } else {
            format!("with {}", fpc.join(", "))
        };
        let heartbeat = match d.heartbeat_max_ms {
            Some(m) => format!("0..={}", u32::from(m).min(MAX_HEARTBEAT_MS)),
            None => "refused".into(),
        };
        let guard = match d.guard_time_max_ms {
            Some(m) => format!("0, or the cycle..={m}"),
            None => "refused".into(),
        };
        let (number, next) = match d.records {
            Some(r) => (
                format!("1..={}", r.last),
                if r.chaining { "allowed" } else { "refused" },
            ),
            None => ("refused (no table)".into(), "—"),
        };
        let link = match d.link {
            Link::Canopen => "CANopen",
            Link::ModbusTcp => "Modbus TCP",
        };
        let _ = writeln!(
            s,
            "| `{}` | {} {} | {link} | {} | {device_type} | {vendor} | {pdo1} | {fpc} | {heartbeat} | {guard} | {number} | {next} |",
            d.id,
            d.vendor,
            d.name,
            profiles.join(", "),
        );
    }
    s
}

#[test]
fn the_documented_limits_are_the_catalogs() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/configuration.md");
    let doc = std::fs::read_to_string(path).expect("docs/configuration.md");
    let table = limits_table();
    assert!(
        doc.contains(&table),
        "docs/configuration.md does not hold the catalog's limits table; it should read:\n\n{table}"
    );
}
