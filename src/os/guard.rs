//! The SIGBUS guard: a mapped file that shrinks (or is rewritten) while we read it must give an
//! error, not kill the process.
//!
//! Reading a page of a shared file mapping that lies past the end of the file raises SIGBUS,
//! whose default action ends the process with no message (exit 135). That happens when another
//! process truncates the file we trace, or rewrites it in place (`cp other.oavm traced.oavm`
//! truncates first). Every byte we read is untrusted anyway, so what we need is only that the
//! read *completes*: the bytes it sees do not matter, as long as we find out afterwards that
//! the file changed and report it.
//!
//! **Mechanism.** Each [`super::MappedFile`] registers its address range here. A SIGBUS
//! handler (installed once, chained to the one it replaces) looks the faulting address up: in
//! a registered range, it maps one anonymous zero page over the faulting page (`MAP_FIXED`),
//! marks the range *faulted* and returns, so the faulting load runs again and reads zeros;
//! outside every range, it hands the signal to the previous handler (Rust's runtime installs
//! one for stack overflows, which falls back to the default action). The file's owner checks
//! [`Registration::faulted`] (and the file's metadata) at the end of each batch and reports
//! "changed while it was being read" instead of whatever the zeros made of the answers.
//!
//! **Cost.** Nothing on the hot path: no check per read. Registering is a few atomic stores.
//!
//! **Limits.** [`SLOTS`] ranges can be registered at once; a map past that is not guarded (it
//! still works; a SIGBUS in it ends the process as before).

use std::mem::MaybeUninit;
use std::sync::Once;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Ranges that can be guarded at once.
pub const SLOTS: usize = 256;

struct Slot {
    /// Start of the range (0: free).
    start: AtomicUsize,
    end: AtomicUsize,
    faulted: AtomicBool,
}

#[allow(clippy::declare_interior_mutable_const)] // a template for the array below, never shared
const FREE: Slot = Slot {
    start: AtomicUsize::new(0),
    end: AtomicUsize::new(0),
    faulted: AtomicBool::new(false),
};

static RANGES: [Slot; SLOTS] = [FREE; SLOTS];
static INSTALL: Once = Once::new();
static PAGE: AtomicUsize = AtomicUsize::new(4096);
/// Whether the handler is installed (false if `sigaction` failed: then nothing is guarded).
static INSTALLED: AtomicBool = AtomicBool::new(false);

/// The action the handler replaced, for signals outside our ranges. Written once, before the
/// handler is installed, and only read after.
struct Previous(std::cell::UnsafeCell<MaybeUninit<libc::sigaction>>);
// SAFETY: written exactly once inside `INSTALL.call_once`, before `sigaction` makes the handler
// (the only reader) reachable; never written again, so every later access is a read.
unsafe impl Sync for Previous {}
static PREVIOUS: Previous = Previous(std::cell::UnsafeCell::new(MaybeUninit::uninit()));

/// A guarded range; unregisters it when dropped.
pub struct Registration {
    slot: Option<usize>,
}

impl Registration {
    /// Whether a read in the range faulted (the file shrank under the map): the bytes read
    /// there were zeros, not the file's.
    pub fn faulted(&self) -> bool {
        self.slot
            .is_some_and(|i| RANGES[i].faulted.load(Ordering::Acquire))
    }
}

impl Drop for Registration {
    fn drop(&mut self) {
        if let Some(i) = self.slot {
            RANGES[i].end.store(0, Ordering::Release);
            RANGES[i].faulted.store(false, Ordering::Release);
            RANGES[i].start.store(0, Ordering::Release);
        }
    }
}

/// Guards `start .. start + len` (a mapping the caller owns and unmaps only after dropping the
/// registration).
pub fn register(start: usize, len: usize) -> Registration {
    install();
    if !INSTALLED.load(Ordering::Acquire) || start == 0 || len == 0 {
        return Registration { slot: None };
    }
    for (i, s) in RANGES.iter().enumerate() {
        // A slot is claimed through `start`; until `end` is stored it matches no address (the
        // handler needs `addr < end`), and nothing reads the range before this returns.
        if s.start
            .compare_exchange(0, start, Ordering::AcqRel, Ordering::Relaxed)
            .is_ok()
        {
            s.faulted.store(false, Ordering::Release);
            s.end.store(start.saturating_add(len), Ordering::Release);
            return Registration { slot: Some(i) };
        }
    }
    Registration { slot: None }
}

fn install() {
    INSTALL.call_once(|| {
        // SAFETY: `sysconf` reads a system constant.
        let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
        if page > 0 {
            PAGE.store(page as usize, Ordering::Relaxed);
        }
        // SAFETY: a zeroed `sigaction` is a valid value (no handler, empty mask, no flags); we
        // fill the fields we use. `sigaction` stores the previous action into PREVIOUS before
        // our handler can run (the handler only reads PREVIOUS once it has been installed),
        // and this runs once (`Once`).
        unsafe {
            let mut action: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = on_sigbus as *const () as libc::sighandler_t;
            action.sa_flags = libc::SA_SIGINFO | libc::SA_ONSTACK;
            libc::sigemptyset(&mut action.sa_mask);
            let previous = (*PREVIOUS.0.get()).as_mut_ptr();
            if libc::sigaction(libc::SIGBUS, &action, previous) == 0 {
                INSTALLED.store(true, Ordering::Release);
            }
        }
    });
}

/// The SIGBUS handler. Async-signal-safe: atomics, `mmap` and `sigaction` (system calls) only.
extern "C" fn on_sigbus(sig: libc::c_int, info: *mut libc::siginfo_t, ctx: *mut libc::c_void) {
    // SAFETY: the kernel passes a valid `siginfo_t` to an SA_SIGINFO handler; for SIGBUS its
    // `si_addr` is the faulting address.
    let addr = unsafe { (*info).si_addr() } as usize;
    let page = PAGE.load(Ordering::Relaxed);
    for s in &RANGES {
        let start = s.start.load(Ordering::Acquire);
        if start == 0 || addr < start || addr >= s.end.load(Ordering::Acquire) {
            continue;
        }
        let at = addr & !(page - 1);
        // SAFETY: `at` is a page inside a mapping registered by its owner, who keeps it mapped
        // while registered. Replacing that page by a private anonymous zero page changes what
        // reads of it return (zeros instead of a SIGBUS), nothing else: the page was readable
        // memory of the same mapping, and the owner only ever reads it through `&[u8]`.
        let p = unsafe {
            libc::mmap(
                at as *mut libc::c_void,
                page,
                libc::PROT_READ,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS | libc::MAP_FIXED,
                -1,
                0,
            )
        };
        if p != libc::MAP_FAILED {
            s.faulted.store(true, Ordering::Release);
            return;
        }
    }
    // Not ours: the previous action.
    // SAFETY: PREVIOUS was written before this handler was installed (see `install`).
    let prev = unsafe { (*PREVIOUS.0.get()).assume_init_ref() };
    let handler = prev.sa_sigaction;
    if handler == libc::SIG_DFL || handler == libc::SIG_IGN {
        // Back to the default action; returning re-runs the faulting access, which then ends
        // the process as it would have without us (ignoring a SIGBUS would loop for ever).
        // SAFETY: a zeroed sigaction is SIG_DFL with no flags.
        unsafe {
            let mut dfl: libc::sigaction = std::mem::zeroed();
            dfl.sa_sigaction = libc::SIG_DFL;
            libc::sigaction(libc::SIGBUS, &dfl, std::ptr::null_mut());
        }
    } else if prev.sa_flags & libc::SA_SIGINFO != 0 {
        // SAFETY: the previous handler was installed with SA_SIGINFO, so it has this signature.
        let f: extern "C" fn(libc::c_int, *mut libc::siginfo_t, *mut libc::c_void) =
            unsafe { std::mem::transmute(handler) };
        f(sig, info, ctx);
    } else {
        // SAFETY: without SA_SIGINFO a handler takes the signal number only.
        let f: extern "C" fn(libc::c_int) = unsafe { std::mem::transmute(handler) };
        f(sig);
    }
}
