//! The integration tests of the library and its binaries, in one test binary with a file per
//! subject (the corruption tests, `tests/corruption/`, are a binary of their own): one binary
//! links the library once, not twenty times, and its tests share the two cores instead of
//! waiting for the longest test of each file in turn.
//!
//!     cargo test --test integration [SUBJECT::]     # e.g. tracing::, paging::, cli::

#[path = "../common/mod.rs"]
mod common;
/// The Rain generator (`cargo run --features tools --example rain`), whose functions `rain` and `animate` call.
#[path = "../../tools/rain.rs"]
#[allow(dead_code)]
mod rain_example;

mod all_hits;
mod animate;
mod architecture;
mod building;
mod cli;
mod docs;
mod fuzz_corpus;
mod geometries;
mod golden;
mod kernels;
mod mapping;
mod mesh_aff;
mod mesh_input;
mod mesh_stream;
mod nearest;
mod paging;
mod rain;
mod render_shaded;
mod ropes;
mod safety;
mod tracing;
mod update;
mod wide;
