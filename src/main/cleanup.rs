//! The temporary output file is removed when the run is cut short by a signal: Ctrl-C
//! (SIGINT), `kill` (SIGTERM), a closed terminal (SIGHUP), or an abort (SIGABRT, as
//! when memory runs out). Otherwise a hidden `.ncpost-*.tmp` file, as large as the
//! output written so far, would be left beside the output.
//!
//! The handler runs at any point of the run, so it only does what is safe there: it
//! removes the one file registered (a path prepared beforehand), restores the signal's
//! default action and raises the signal again, so the process ends as the signal says
//! (the shell reports 130 for SIGINT, 143 for SIGTERM).

use std::ffi::CString;
use std::path::Path;
use std::sync::Once;
use std::sync::atomic::{AtomicPtr, Ordering};

/// The temporary file to remove on a signal (a NUL-terminated path), or null.
static TEMP: AtomicPtr<libc::c_char> = AtomicPtr::new(std::ptr::null_mut());

/// The signals after which the temporary file is removed.
const SIGNALS: [libc::c_int; 4] = [libc::SIGINT, libc::SIGTERM, libc::SIGHUP, libc::SIGABRT];

extern "C" fn on_signal(sig: libc::c_int) {
    let path = TEMP.load(Ordering::SeqCst);
    // SAFETY: `path` is null or a leaked, never freed C string; `unlink`, `signal` and
    // `raise` are async-signal-safe.
    unsafe {
        if !path.is_null() {
            libc::unlink(path);
        }
        libc::signal(sig, libc::SIG_DFL);
        libc::raise(sig);
    }
}

/// Installs the handler once; a signal the process was started with ignored (`nohup`)
/// stays ignored.
fn install() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        for sig in SIGNALS {
            let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            // SAFETY: `on_signal` only calls async-signal-safe functions.
            unsafe {
                if libc::signal(sig, handler) == libc::SIG_IGN {
                    libc::signal(sig, libc::SIG_IGN);
                }
            }
        }
    });
}

/// While it lives, the file it was given is removed on a signal. Create it before the
/// temporary file, so that it is dropped after it (the file is gone by then).
pub struct Guard;

impl Guard {
    /// Installs the handler; nothing is registered yet.
    pub fn new() -> Guard {
        install();
        Guard
    }

    /// Registers `path` as the file to remove on a signal.
    pub fn set(&self, path: &Path) {
        use std::os::unix::ffi::OsStrExt;
        if let Ok(c) = CString::new(path.as_os_str().as_bytes()) {
            // Leaked on purpose: a handler may be reading the previous one.
            TEMP.store(c.into_raw(), Ordering::SeqCst);
        }
    }
}

impl Drop for Guard {
    fn drop(&mut self) {
        TEMP.store(std::ptr::null_mut(), Ordering::SeqCst);
    }
}
