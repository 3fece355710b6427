//! Cost per frame of the SDO server and client state machines.
//!
//! Run: `cargo bench -p drivers --bench sdo`. Each benchmark runs a whole transfer per
//! iteration and declares its frame count as the throughput, so criterion's "elem/s" is frames
//! handled per second and time / frames is the cost of one frame.

// criterion_group! generates an undocumented public function.
#![allow(missing_docs)]

use criterion::{Criterion, Throughput, black_box, criterion_group, criterion_main};
use drivers::can::Frame;
use drivers::canopen::od::ObjectAccess;
use drivers::canopen::sdo::{
    Completion, DownloadMode, SdoClient, SdoClientConfig, SdoServer, SdoServerConfig,
};
use drivers::canopen::{AbortCode, Address, NodeId};
use drivers::time::Instant;

const VAR: Address = Address::new(0x6083, 0);
const DOMAIN: Address = Address::new(0x2000, 1);

/// A U32 variable and a 4 KiB DOMAIN.
struct Od {
    var: u32,
    domain: Vec<u8>,
}

impl ObjectAccess for Od {
    fn size(&self, addr: Address) -> Result<usize, AbortCode> {
        match addr {
            VAR => Ok(4),
            DOMAIN => Ok(self.domain.len()),
            _ => Err(AbortCode::NoObject),
        }
    }
    fn read(&mut self, addr: Address, offset: usize, buf: &mut [u8]) -> Result<usize, AbortCode> {
        let bytes = self.var.to_le_bytes();
        let v: &[u8] = match addr {
            VAR => &bytes,
            DOMAIN => &self.domain,
            _ => return Err(AbortCode::NoObject),
        };
        let rest = v.get(offset..).unwrap_or(&[]);
        let n = rest.len().min(buf.len());
        buf[..n].copy_from_slice(&rest[..n]);
        Ok(n)
    }
    fn write(&mut self, addr: Address, data: &[u8]) -> Result<(), AbortCode> {
        match addr {
            VAR => {
                self.var =
                    u32::from_le_bytes(data.try_into().map_err(|_| AbortCode::TypeMismatch)?);
                Ok(())
            }
            DOMAIN => {
                self.domain.clear();
                self.domain.extend_from_slice(data);
                Ok(())
            }
            _ => Err(AbortCode::NoObject),
        }
    }
}

fn od() -> Od {
    Od {
        var: 0x1234_5678,
        domain: (0..4096).map(|i| (i * 13) as u8).collect(),
    }
}

fn node() -> NodeId {
    NodeId::new(1).unwrap()
}

type Client = SdoClient<4, 4096>;
type Server = SdoServer<4096>;

/// Runs one transfer between a fresh pair and records the frames each side sent.
fn record(start: impl Fn(&mut Client)) -> (Vec<Frame>, Vec<Frame>) {
    let mut c = Client::new(node(), SdoClientConfig::default());
    let mut s = Server::new(node(), SdoServerConfig::default());
    let mut o = od();
    start(&mut c);
    let (mut c2s, mut s2c) = (Vec::new(), Vec::new());
    let t = Instant::ZERO;
    loop {
        let mut moved = false;
        while let Some(f) = c.poll_transmit(t) {
            s.handle_frame(&f, t, &mut o);
            c2s.push(f);
            moved = true;
        }
        while let Some(f) = s.poll_transmit(t) {
            c.handle_frame(&f, t);
            s2c.push(f);
            moved = true;
        }
        if !moved {
            break;
        }
    }
    assert!(c.poll_event().unwrap().outcome.is_ok());
    (c2s, s2c)
}

/// Server cost: replays the client's frames, draining the server's replies after each.
fn bench_server(c: &mut Criterion, name: &str, c2s: &[Frame]) {
    let mut g = c.benchmark_group("sdo_server");
    g.throughput(Throughput::Elements(c2s.len() as u64));
    let mut s = Server::new(node(), SdoServerConfig::default());
    let mut o = od();
    let t = Instant::ZERO;
    g.bench_function(name, |b| {
        b.iter(|| {
            for f in c2s {
                s.handle_frame(black_box(f), t, &mut o);
                while let Some(r) = s.poll_transmit(t) {
                    black_box(r);
                }
            }
            while s.poll_event().is_some() {}
        })
    });
    g.finish();
}

/// Client cost: starts the request, then replays the server's frames, draining the client's
/// frames after each. `frames` is the count the cost is spread over: the frames received for an
/// upload, the segments sent for a block download.
fn bench_client(
    c: &mut Criterion,
    name: &str,
    start: &dyn Fn(&mut Client),
    s2c: &[Frame],
    frames: usize,
) {
    let mut g = c.benchmark_group("sdo_client");
    g.throughput(Throughput::Elements(frames as u64));
    let mut cl = Client::new(node(), SdoClientConfig::default());
    let t = Instant::ZERO;
    g.bench_function(name, |b| {
        b.iter(|| {
            start(&mut cl);
            while let Some(f) = cl.poll_transmit(t) {
                black_box(f);
            }
            for f in s2c {
                cl.handle_frame(black_box(f), t);
                while let Some(r) = cl.poll_transmit(t) {
                    black_box(r);
                }
            }
            match cl.poll_event().map(|e| e.outcome) {
                Some(Ok(Completion::Uploaded(d))) => {
                    black_box(d);
                }
                Some(Ok(Completion::Downloaded)) => {}
                other => panic!("transfer failed: {other:?}"),
            }
        })
    });
    g.finish();
}

fn sdo(c: &mut Criterion) {
    let value: Vec<u8> = (0..4096).map(|i| (i * 7) as u8).collect();
    let exp = |c: &mut Client| {
        c.upload(VAR).unwrap();
    };
    let seg = |c: &mut Client| {
        c.upload(DOMAIN).unwrap();
    };
    let blk = |c: &mut Client| {
        c.download(DOMAIN, &value, DownloadMode::Block).unwrap();
    };
    let (exp_c2s, exp_s2c) = record(exp);
    let (seg_c2s, seg_s2c) = record(seg);
    let (blk_c2s, blk_s2c) = record(blk);
    bench_server(c, "expedited_upload", &exp_c2s);
    bench_server(c, "segmented_upload_4k", &seg_c2s);
    bench_server(c, "block_download_4k", &blk_c2s);
    bench_client(c, "expedited_upload", &exp, &exp_s2c, exp_s2c.len());
    bench_client(c, "segmented_upload_4k", &seg, &seg_s2c, seg_s2c.len());
    bench_client(c, "block_download_4k", &blk, &blk_s2c, blk_c2s.len());
}

criterion_group!(benches, sdo);
criterion_main!(benches);
