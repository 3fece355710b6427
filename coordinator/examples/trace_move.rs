//! Debug trace (temporary).
use coordinator::command::Command;
use coordinator::config::{Config, EXAMPLE};
use coordinator::records::MAX_GROUP_AXES;
use coordinator::runtime::plan::plan;
use coordinator::runtime::run::{RunOptions, VirtualRun};
use coordinator::runtime::script::{Phase, ScriptOptions};
fn main() {
    let plan = plan(&Config::parse(EXAMPLE).unwrap()).unwrap();
    let opts = RunOptions {
        duration: None,
        virtual_time: true,
        status_every: None,
        script: ScriptOptions {
            chains: false,
            home: true,
        },
    };
    let mut run = VirtualRun::new(&plan, &opts).unwrap();
    let mut out = Vec::new();
    while run.script.phase() != Phase::Running {
        run.step(&mut out);
    }
    for _ in 0..10 {
        run.step(&mut out);
    }
    let mut p = [0i64; MAX_GROUP_AXES];
    p[0] = 60000;
    p[1] = 120000;
    println!(
        "{:?}",
        run.core.cycle.command(&Command::MoveGroup {
            group: 0,
            positions: p,
            velocity_percent: 100
        })
    );
    for k in 0..1200 {
        run.step(&mut out);
        if k % 10 == 0 {
            let x = run.core.cycle.axis_status(0).unwrap();
            let y = run.core.cycle.axis_status(1).unwrap();
            println!(
                "{k:5} x set {:7} act {:7} {:?} mc {} | y set {:7} act {:7} {:?} mc {} f {:?}",
                x.setpoint,
                x.feedback.position,
                x.feedback.state,
                x.feedback.motion_complete,
                y.setpoint,
                y.feedback.position,
                y.feedback.state,
                y.feedback.motion_complete,
                y.fault
            );
        }
    }
    println!("{}", String::from_utf8_lossy(&out));
}
