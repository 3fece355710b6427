//! The little of a peripheral access crate that RTIC needs for the MPS2 AN385 (a Cortex-M3
//! with the CMSDK peripherals): the NVIC's priority bits and the external interrupts the
//! application dispatches its software tasks on. The application drives no peripheral of the
//! board (SysTick is the core's), so nothing else is described; a port to a real board takes
//! that board's PAC instead (docs/architecture.md).

/// Priority bits RTIC uses (the Cortex-M3 has at least 3; QEMU models 8: the lower ones read 0).
pub const NVIC_PRIO_BITS: u8 = 3;

/// The external interrupts named in the vector table (AN385: IRQ 0 and 1 are UART 0's receive
/// and transmit interrupts; the application only pends them in software, as RTIC's dispatchers
/// of its software tasks).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
#[allow(clippy::upper_case_acronyms)]
pub enum Interrupt {
    /// UART 0 receive.
    UARTRX0 = 0,
    /// UART 0 transmit.
    UARTTX0 = 1,
}

// SAFETY: the numbers are the board's external interrupt numbers, all below its 32.
unsafe impl cortex_m::interrupt::InterruptNumber for Interrupt {
    fn number(self) -> u16 {
        self as u16
    }
}

/// The name RTIC looks the dispatchers up by (as svd2rust PACs export it).
pub use Interrupt as interrupt;

unsafe extern "C" {
    fn UARTRX0();
    fn UARTTX0();
}

/// One entry of the vector table.
#[doc(hidden)]
pub union Vector {
    handler: unsafe extern "C" fn(),
    reserved: u32,
}

/// The external part of the vector table, after the core's exceptions (cortex-m-rt's
/// `device` feature links it there).
#[doc(hidden)]
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
pub static __INTERRUPTS: [Vector; 32] = {
    let mut v = [const { Vector { reserved: 0 } }; 32];
    v[0] = Vector { handler: UARTRX0 };
    v[1] = Vector { handler: UARTTX0 };
    v
};
