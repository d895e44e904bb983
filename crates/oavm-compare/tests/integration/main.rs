//! The comparison crate's integration tests, in one binary with a file per subject: the
//! structures against the f64 brute force (`structures`), `oavm-bench` end to end
//! (`bench_cli`), the shadow-ray variants of the multi-index tree (`shadow`).
//!
//!     cargo test -p oavm-compare --test integration [SUBJECT::]

#[path = "../common/mod.rs"]
mod common;

mod bench_cli;
mod shadow;
mod structures;
