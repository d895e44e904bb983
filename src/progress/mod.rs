//! Progress of long work: the builder's phases and a streamed batch's rays report through
//! [`Progress`], which the library never draws; the binaries and the Python bindings draw it
//! with [`Bar`] (feature `progress`, on with `cli`). Below both `pack` and `logical`, which
//! report through it.

#[cfg(feature = "progress")]
mod bar;

#[cfg(feature = "progress")]
pub use bar::Bar;

/// What the library reports while it works (the builder's phases, a stream's rays): a phase
/// with its amount of work (bytes of the input, or items) if known, then how much of it is
/// done. The binaries and the Python bindings draw it as a progress bar ([`Bar`], feature
/// `progress`); the library never draws.
pub trait Progress: Sync {
    fn phase(&self, _name: &str, _total: Option<u64>, _bytes: bool) {}
    fn at(&self, _done: u64) {}
    /// A note on the phase (what else it has done: blocks read, say).
    fn note(&self, _text: &str) {}
}

/// No progress reporting.
pub struct Quiet;

impl Progress for Quiet {}
