//! candump `-l` logs as the coordinator's `--capture` writes them, read back for tests.

use std::path::Path;

/// One frame of a candump `-l` log: time (s), identifier, data (`None` for a remote frame).
#[derive(Debug, Clone, PartialEq)]
pub struct Logged {
    /// Seconds (Unix time).
    pub time: f64,
    /// The CAN identifier.
    pub id: u32,
    /// The data; `None` for a remote frame.
    pub data: Option<Vec<u8>>,
}

/// Reads a candump `-l` log: `(1712345678.123456) IFACE 181#00112233`.
pub fn read_log(path: &Path) -> Vec<Logged> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .map(|l| {
            let mut parts = l.split_whitespace();
            let time = parts.next().unwrap();
            let _iface = parts.next().unwrap();
            let frame = parts.next().unwrap();
            let (id, data) = frame.split_once('#').unwrap();
            let data = (!data.starts_with('R')).then(|| {
                (0..data.len())
                    .step_by(2)
                    .map(|i| u8::from_str_radix(&data[i..i + 2], 16).unwrap())
                    .collect()
            });
            Logged {
                time: time.trim_matches(['(', ')']).parse().unwrap(),
                id: u32::from_str_radix(id, 16).unwrap(),
                data,
            }
        })
        .collect()
}

/// The SYNC's identifier.
pub const SYNC: u32 = 0x080;

/// Each frame with the number of SYNCs seen up to and including it (the SYNC it follows).
pub fn numbered(log: &[Logged]) -> Vec<(u64, &Logged)> {
    let mut n = 0;
    log.iter()
        .map(|f| {
            n += u64::from(f.id == SYNC);
            (n, f)
        })
        .collect()
}

/// The SYNC number after which the frames `cob` first carry other data than before, looking
/// only after SYNC `from`; with the data before and after.
pub fn first_change(log: &[Logged], cob: u32, from: u64) -> Option<(u64, Vec<u8>, Vec<u8>)> {
    let mut last: Option<&Vec<u8>> = None;
    for (n, f) in numbered(log) {
        if f.id != cob {
            continue;
        }
        let Some(d) = &f.data else { continue };
        if n > from
            && let Some(prev) = last
            && prev != d
        {
            return Some((n, prev.clone(), d.clone()));
        }
        last = Some(d);
    }
    None
}
