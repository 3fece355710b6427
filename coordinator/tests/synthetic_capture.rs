//! `synthetic::capture_moving` on machines the criterion bench does not use (FHPP axes moving
//! alone, CiA 402 axes in groups): every axis moves in the captured step. In its own process:
//! a virtual run stops at the process's stop flag, which the library's signal test raises.

use coordinator::config::Config;
use coordinator::runtime::plan::plan;
use coordinator::runtime::synthetic::{Kinds, Spec, capture_moving, config_of};

#[test]
fn a_captured_step_has_every_axis_moving() {
    for (kinds, grouped) in [(Kinds::Fhpp, false), (Kinds::Cia402, true)] {
        let spec = Spec {
            axes: 4,
            kinds,
            group_size: grouped.then_some(8),
        };
        let p = plan(&Config::parse(&config_of(&spec)).unwrap()).unwrap();
        let c = capture_moving(&p, grouped).unwrap_or_else(|e| panic!("{spec:?}: {e}"));
        assert!(!c.frames.is_empty() || !c.images.is_empty());
    }
}
