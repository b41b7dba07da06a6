//! A polite stop for everything that runs a trial: SIGTERM, SIGINT (Ctrl-C) and SIGHUP end
//! the running trial as its other ends do (a stop command with the reason to the robot side,
//! the trial file written), then the command exits with status 128 + the signal's number. A
//! second such signal exits at once. A kill that cannot be caught (SIGKILL) still leaves the
//! trial's last checkpoint (see [`crate::keep`]).
//!
//! Signals belong to the process, so the request is process-wide: the command installs the
//! handlers once ([`install`]) and every loop asks [`requested`].

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};

/// The signal received (0: none).
static RECEIVED: OnceLock<Arc<AtomicUsize>> = OnceLock::new();

/// The signals that ask for a polite stop.
const SIGNALS: [i32; 3] = [
    signal_hook::consts::SIGTERM,
    signal_hook::consts::SIGINT,
    signal_hook::consts::SIGHUP,
];

/// Installs the handlers (once per process; later calls do nothing).
pub fn install() -> Result<(), crate::LiveError> {
    if RECEIVED.get().is_some() {
        return Ok(());
    }
    let received = Arc::new(AtomicUsize::new(0));
    let armed = Arc::new(AtomicBool::new(false));
    for sig in SIGNALS {
        let err = |e: std::io::Error| crate::LiveError::Net(format!("signal handler: {e}"));
        // A second signal, once the first armed this, exits at once.
        signal_hook::flag::register_conditional_shutdown(sig, 128 + sig, Arc::clone(&armed))
            .map_err(err)?;
        signal_hook::flag::register_usize(sig, Arc::clone(&received), sig as usize).map_err(err)?;
        signal_hook::flag::register(sig, Arc::clone(&armed)).map_err(err)?;
    }
    let _ = RECEIVED.set(received);
    Ok(())
}

/// The signal's number, when one asked for a stop.
pub fn signal() -> Option<i32> {
    let n = RECEIVED.get()?.load(Ordering::SeqCst);
    (n != 0).then(|| i32::try_from(n).unwrap_or(i32::MAX))
}

/// Why to stop, when a signal asked for it: "fishprobe received SIGTERM".
pub fn requested() -> Option<String> {
    signal().map(|s| format!("fishprobe received {}", name(s)))
}

/// The exit status after a stop that a signal asked for (128 + its number, the shell's
/// convention), if one did.
pub fn exit_status() -> Option<i32> {
    signal().map(|s| 128 + s)
}

fn name(sig: i32) -> String {
    match sig {
        signal_hook::consts::SIGTERM => "SIGTERM".into(),
        signal_hook::consts::SIGINT => "SIGINT".into(),
        signal_hook::consts::SIGHUP => "SIGHUP".into(),
        n => format!("signal {n}"),
    }
}
