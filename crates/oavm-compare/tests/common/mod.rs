//! Fixtures shared by this crate's integration tests, the few of `oavm`'s `tests/common` they
//! use (that module names `oavm`'s binaries, which are not this crate's): the shared scenes (a
//! missing `../shared` is a failure, never a skip), the repository's bundled data, and running
//! `oavm-bench`.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// The repository's root: this crate is `crates/oavm-compare` in it.
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A scene from `../shared/scenes`, beside the checkout. Panics (fails the test) if it is
/// missing: the tests need `../shared` beside the checkout, as CI provides it.
pub fn shared_scene(rel: &str) -> PathBuf {
    let p = repo_root().join("../shared/scenes").join(rel);
    assert!(
        p.exists(),
        "{} is missing: the tests read ../shared/scenes beside the checkout (CI provides it)",
        p.display()
    );
    p
}

/// A file of the repository's `data/` (the bundled bunny).
pub fn data(rel: &str) -> PathBuf {
    let p = repo_root().join("data").join(rel);
    assert!(p.exists(), "{} is missing", p.display());
    p
}

/// A binary of this crate you can run: `oavm-bench`.
pub fn bin(name: &str) -> Command {
    let path = match name {
        "oavm-bench" => env!("CARGO_BIN_EXE_oavm-bench"),
        _ => panic!("no binary {name} in oavm-compare"),
    };
    Command::new(path)
}

/// Runs `cmd`, returning its output; its stdout and stderr as text.
pub fn run(cmd: &mut Command) -> (Output, String, String) {
    let out = cmd.output().expect("run");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    (out, stdout, stderr)
}
