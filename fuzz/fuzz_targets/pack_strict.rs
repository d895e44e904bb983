#![no_main]

// Not fuzzed (no corpus): for minimising the reproducers of `OPEN_BUGS` (tests/fuzz_corpus.rs)
// with `cargo fuzz tmin`, since `pack` steps around their bug.
#[path = "../targets.rs"]
mod targets;

libfuzzer_sys::fuzz_target!(|data: &[u8]| targets::pack_strict(data));
