//! The stack's high-water mark (the stack is painted with a pattern, and the lowest address no
//! longer holding it is how deep the stack went) and the sizes of the image's sections, from
//! cortex-m-rt's linker symbols.

/// The paint.
const PAINT: u32 = 0xC0DE_57AC;
/// Bytes left unpainted below the painter's own stack pointer (its frame and a margin).
const MARGIN: usize = 256;

unsafe extern "C" {
    static _stack_start: u32;
    static _stack_end: u32;
    static __sbss: u32;
    static __suninit: u32;
    static __euninit: u32;
    static __ebss: u32;
    static __sdata: u32;
    static __edata: u32;
    static __stext: u32;
    static __etext: u32;
    static __srodata: u32;
    static __erodata: u32;
}

fn addr(s: &u32) -> usize {
    s as *const u32 as usize
}

/// Paints the free stack, from the stack's lowest address (after `.bss` and `.uninit`) to just
/// below the current stack pointer.
pub fn paint() {
    // SAFETY: linker symbols; only their addresses are taken.
    let (bottom, sp) = unsafe { (addr(&_stack_end), cortex_m::register::msp::read() as usize) };
    let mut p = bottom.next_multiple_of(4);
    while p + MARGIN < sp {
        // SAFETY: between the stack's lowest address and the live stack: memory nothing else uses.
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// The deepest the stack went since the last [`paint`], bytes below its top.
pub fn used() -> u32 {
    // SAFETY: linker symbols; only their addresses are taken.
    let (bottom, top) = unsafe { (addr(&_stack_end).next_multiple_of(4), addr(&_stack_start)) };
    let mut p = bottom;
    // SAFETY: reads within the stack's region.
    while p < top && unsafe { core::ptr::read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    (top - p) as u32
}

/// The sizes of the image's sections, bytes.
#[derive(Clone, Copy, Debug)]
pub struct Sections {
    /// Initialised statics (RAM, with their initial values in flash).
    pub data: u32,
    /// Zeroed statics (RAM).
    pub bss: u32,
    /// Statics left uninitialised until written (RAM: RTIC's resources).
    pub uninit: u32,
    /// Code (flash).
    pub text: u32,
    /// Constants (flash).
    pub rodata: u32,
}

/// The sizes of `.data`, `.bss`, `.uninit`, `.text` and `.rodata`.
pub fn sections() -> Sections {
    // SAFETY: linker symbols; only their addresses are taken.
    unsafe {
        Sections {
            data: (addr(&__edata) - addr(&__sdata)) as u32,
            bss: (addr(&__ebss) - addr(&__sbss)) as u32,
            uninit: (addr(&__euninit) - addr(&__suninit)) as u32,
            text: (addr(&__etext) - addr(&__stext)) as u32,
            rodata: (addr(&__erodata) - addr(&__srodata)) as u32,
        }
    }
}

/// Bytes below a task's entry that [`paint_window`] paints: deeper use is reported as this.
pub const WINDOW: usize = 64 * 1024;

/// Paints [`WINDOW`] bytes below the current stack pointer (less the painter's margin) and
/// returns that stack pointer: [`window_used`] then tells how deep the stack went below it.
/// For a task nothing preempts (the highest priority), so the window is its own.
#[inline(always)]
pub fn paint_window() -> usize {
    let sp = cortex_m::register::msp::read() as usize;
    // SAFETY: linker symbol; only its address is taken.
    let floor = unsafe { addr(&_stack_end) };
    let mut p = sp.saturating_sub(WINDOW).max(floor).next_multiple_of(4);
    while p + MARGIN < sp {
        // SAFETY: below the live stack, above its lowest address: nothing else uses it.
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
    sp
}

/// How deep the stack went below `sp` since [`paint_window`] returned it, bytes.
pub fn window_used(sp: usize) -> u32 {
    // SAFETY: linker symbol; only its address is taken.
    let floor = unsafe { addr(&_stack_end) };
    let mut p = sp.saturating_sub(WINDOW).max(floor).next_multiple_of(4);
    // SAFETY: reads within the window just painted.
    while p < sp && unsafe { core::ptr::read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    (sp - p) as u32
}
