//! What posing reads, counted for the tests that keep it linear in the input (counts, not
//! timings): the key records the spline and key searches touch, and the animations evaluated.
//! Per thread, and only in test builds; elsewhere the calls compile to nothing.

#[cfg(test)]
use std::cell::Cell;

#[cfg(test)]
thread_local! {
    static KEYS: Cell<u64> = const { Cell::new(0) };
    static EVALUATIONS: Cell<u64> = const { Cell::new(0) };
}

/// `n` key records read.
#[inline(always)]
pub(crate) fn keys(n: usize) {
    #[cfg(test)]
    KEYS.with(|c| c.set(c.get() + n as u64));
    #[cfg(not(test))]
    let _ = n;
}

/// One animation evaluated.
#[inline(always)]
pub(crate) fn evaluation() {
    #[cfg(test)]
    EVALUATIONS.with(|c| c.set(c.get() + 1));
}

/// The counts since the last call: `(keys, evaluations)`.
#[cfg(test)]
pub(crate) fn take() -> (u64, u64) {
    (
        KEYS.with(|c| c.replace(0)),
        EVALUATIONS.with(|c| c.replace(0)),
    )
}
