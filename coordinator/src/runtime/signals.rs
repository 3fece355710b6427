//! The stop flag: SIGINT, SIGTERM, SIGHUP and SIGQUIT all ask for the same safe stop.

use std::sync::Once;
use std::sync::atomic::AtomicBool;

static STOP: AtomicBool = AtomicBool::new(false);
static INSTALL: Once = Once::new();

/// The flag SIGINT, SIGTERM, SIGHUP (the terminal closed) and SIGQUIT set: each leads to the same
/// safe stop. The first call installs the handlers (signal-hook's `flag` module: the handler
/// only stores to the atomic, which is async-signal-safe). The run loop polls it each cycle,
/// stops the axes with their configured deceleration, disables the drives and publishes the
/// state before leaving (bounded: at most 3 s for the stop and 3 s for the disable, see
/// `runtime::script`). A second SIGINT while the flag is set ends the process at once (exit
/// status 130), for a shutdown that hangs.
pub fn stop_flag() -> &'static AtomicBool {
    INSTALL.call_once(|| {
        use signal_hook::consts::{SIGHUP, SIGINT, SIGQUIT, SIGTERM};
        // Registration fails only for the forbidden signals (SIGKILL, SIGSTOP...), not for
        // these; there is nothing useful to do with an error here.
        let _ = signal_hook::flag::register_conditional_shutdown(SIGINT, 130, &STOP);
        for sig in [SIGINT, SIGTERM, SIGHUP, SIGQUIT] {
            let _ = signal_hook::flag::register(sig, &STOP);
        }
    });
    &STOP
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::Ordering;

    #[test]
    fn sigterm_sets_the_stop_flag() {
        let flag = stop_flag();
        assert!(!flag.load(Ordering::SeqCst));
        // SAFETY: raise sends a signal to this thread; the handler installed above only sets
        // the flag.
        assert_eq!(unsafe { libc::raise(libc::SIGTERM) }, 0);
        assert!(flag.load(Ordering::SeqCst));
        assert!(std::ptr::eq(flag, stop_flag()));
    }
}
