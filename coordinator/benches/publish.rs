//! Publishing the machine state on the cycle thread (`cargo bench -p coordinator --bench
//! publish`): loan a sample, write the state in place, send — beside a bare iceoryx2 publisher
//! of the same payload that copies a prepared `MachineState` into its loan (the least any
//! publisher of this payload does).

// criterion_group! generates an undocumented `pub fn`.
#![allow(missing_docs)]

use std::time::Duration;

use coordinator::config::{Config, EXAMPLE};
use coordinator::runtime::plan::{MachinePlan, plan};
use coordinator::runtime::run::RunOptions;
use coordinator::runtime::script::{Phase, ScriptOptions};
use coordinator::runtime::shm::{StateSide, StaticInfo};
use coordinator::runtime::synthetic;
use coordinator::runtime::virtual_clock::VirtualRun;
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use iceoryx2::prelude::*;
use shm_api::contract::MachineState;

fn running(plan: &MachinePlan) -> VirtualRun<'_> {
    let opts = RunOptions {
        duration: None,
        virtual_time: true,
        status_every: None,
        script: ScriptOptions {
            demo: true,
            chains: true,
            home: true,
        },
        shm: None,
        capture: None,
        record: None,
    };
    let mut run = VirtualRun::new(plan, &opts).unwrap();
    let mut out = Vec::new();
    while run.lp.script.phase() != Phase::Running {
        run.step(&mut out);
    }
    for _ in 0..50 {
        run.step(&mut out);
    }
    run
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("publish");
    g.measurement_time(Duration::from_secs(3));
    g.warm_up_time(Duration::from_secs(1));
    let example = plan(&Config::parse(EXAMPLE).unwrap()).unwrap();
    let big = plan(&Config::parse(&synthetic::config(128, 8)).unwrap()).unwrap();
    let node = NodeBuilder::new().create::<ipc::Service>().unwrap();
    for (name, p) in [("4 axes", &example), ("128 axes", &big)] {
        let run = running(p);
        let prefix = format!("bench-publish-{}-{}", p.axes.len(), std::process::id());
        let mut side = StateSide::create(&prefix, StaticInfo::new(p, true)).unwrap();
        // One subscribed client, so that every send delivers (as the bare pair below does).
        let state_name: ServiceName = format!("{prefix}/state").as_str().try_into().unwrap();
        let service = node
            .service_builder(&state_name)
            .publish_subscribe::<MachineState>()
            .open()
            .unwrap();
        let _client = service.subscriber_builder().create().unwrap();
        g.bench_function(BenchmarkId::new("coordinator state", name), |b| {
            b.iter(|| side.publish(&run.stepper.cycle, 1))
        });
    }
    // The bare pair: a raw iceoryx2 publisher of the same payload.
    let name: ServiceName = format!("bench-publish-bare-{}", std::process::id())
        .as_str()
        .try_into()
        .unwrap();
    let service = node
        .service_builder(&name)
        .publish_subscribe::<MachineState>()
        .history_size(1)
        .subscriber_max_buffer_size(64)
        .enable_safe_overflow(true)
        .open_or_create()
        .unwrap();
    let publisher = service.publisher_builder().create().unwrap();
    // A subscriber, as in the coordinator's case, so that send delivers somewhere.
    let _sub = service.subscriber_builder().create().unwrap();
    let state: Box<MachineState> = {
        let mut s = publisher.loan_uninit().unwrap();
        // SAFETY: MachineState is plain integers; all-zero is a valid value.
        let s = unsafe {
            s.payload_mut().as_mut_ptr().write_bytes(0, 1);
            s.assume_init()
        };
        Box::new(*s)
    };
    g.bench_function("bare iceoryx2: loan, copy, send", |b| {
        b.iter(|| {
            let s = publisher.loan_uninit().unwrap();
            let s = s.write_payload(*state);
            s.send().unwrap();
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
