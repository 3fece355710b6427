//! Cyclic synchronous modes end to end in virtual time: generic CiA 402 drives (the project's
//! simulator) commanded by the coordinator's own cycle, boot and axes.

use std::time::Duration;

use coordinator::config::Config;
use coordinator::ids::AxisId;
use coordinator::runtime::plan::plan;
use coordinator::runtime::run::RunOptions;
use coordinator::runtime::script::ScriptOptions;
use coordinator::runtime::virtual_clock::VirtualRun;

fn opts() -> RunOptions {
    RunOptions {
        duration: Some(Duration::from_secs(3)),
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
    }
}

#[test]
fn debug_csp() {
    let text = std::fs::read_to_string("/tmp/csp/one1.toml").unwrap();
    let cfg = Config::parse(&text).unwrap();
    let plan = plan(&cfg).unwrap();
    let mut run = VirtualRun::new(&plan, &opts()).unwrap();
    let mut out = Vec::new();
    for k in 0..260 {
        run.step(&mut out);
        let st = run.stepper.cycle.axis_status(0 as AxisId).unwrap();
        let d = run.io.drive_mut("a1").unwrap().cia402_mut().unwrap();
        let sw = d.statusword();
        let mode = d.mode();
        let pos = d.actual();
        let ax = *d.axis().status();
        eprintln!(
            "  axis set {} setv {} vel {}",
            ax.setpoint, ax.setpoint_velocity, ax.velocity
        );
        eprintln!(
            "k {k} set {} pos {} fbpos {} moving {} sw {sw:04X} mode {} drive_state {:?} od607A {:?}",
            st.setpoint,
            pos,
            st.feedback.position,
            st.moving,
            mode.code(),
            d.drive_state(),
            (
                d.od().get_u32(drivers::canopen::Address::new(0x607F, 0)),
                d.od().get_u32(drivers::canopen::Address::new(0x6083, 0)),
                d.od().get_u8(drivers::canopen::Address::new(0x60C2, 1)),
                d.od().get_i8(drivers::canopen::Address::new(0x60C2, 2))
            ),
        );
    }
    eprintln!("{}", String::from_utf8_lossy(&out));
}
