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

/// The lines a step asks for before it starts (what `timing step` reads for its memory floor):
/// lines of the state itself, each on a line boundary, more of them for more axes.
#[test]
fn the_hot_lines_are_lines_of_the_state_and_grow_with_the_axes() {
    let lines_of = |axes: usize| {
        let spec = Spec {
            axes,
            kinds: Kinds::Mixed,
            group_size: Some(8),
        };
        let p = plan(&Config::parse(&config_of(&spec)).unwrap()).unwrap();
        let c = capture_moving(&p, true).unwrap_or_else(|e| panic!("{spec:?}: {e}"));
        let base = (&*c.cycle as *const _ as *const u8) as isize;
        let size = std::mem::size_of_val(&*c.cycle) as isize;
        let mut v = Vec::new();
        c.cycle.for_each_hot_line(&mut |o| v.push(o));
        for &o in &v {
            assert!(
                o > -64 && o < size,
                "{axes} axes: line at {o} of a {size}-byte state"
            );
            assert_eq!((base + o) % 64, 0, "{axes} axes: {o} is not a line's start");
        }
        v.sort_unstable();
        v.dedup();
        v.len()
    };
    let (four, eight) = (lines_of(4), lines_of(8));
    assert!(four > 4, "{four} lines for 4 axes");
    assert!(eight > four, "{eight} lines for 8 axes, {four} for 4");
}
