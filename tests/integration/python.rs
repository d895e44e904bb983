//! The Python bindings' tests (`python/tests`, pytest), run by `cargo test`: builds the
//! extension into a virtual environment under the target directory (`target/python-venv`,
//! made on first use with `python3 -m venv`, or `$OAVM_PYTHON -m venv`), installs what the tests
//! need (`python/requirements-test.txt`, pinned), installs the package with
//! `pip install ./python` (maturin, `dev` profile: it builds in seconds once the dependencies
//! are built, and the tests trace small meshes), and runs pytest with the paths of this build's
//! `oavm-pack` and `oavm-trace`, whose output files the answers must equal byte for byte.
//!
//! Nothing here is skipped: no Python, no network for a first install, or a failing pytest is
//! a failing test, with pip's or pytest's output.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root().join("target"), PathBuf::from)
}

/// Runs `cmd`, failing the test with its output if it fails.
fn run(what: &str, cmd: &mut Command) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{what}: cannot run {cmd:?}: {e}"));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success(),
        "{what} failed ({}):\n{text}",
        out.status
    );
    text
}

/// The virtual environment, made if absent.
fn venv() -> PathBuf {
    let venv = target_dir().join("python-venv");
    let python = venv.join("bin").join("python");
    if !python.is_file() {
        let base = std::env::var("OAVM_PYTHON").unwrap_or_else(|_| "python3".into());
        let version = run(
            "the Python interpreter",
            Command::new(&base).args([
                "-c",
                "import sys; assert sys.version_info >= (3, 9), sys.version; print(sys.version)",
            ]),
        );
        eprintln!("python.rs: making {} with {base} {version}", venv.display());
        run(
            "python -m venv",
            Command::new(&base).arg("-m").arg("venv").arg(&venv),
        );
    }
    python
}

fn pip(python: &Path, args: &[&str]) -> String {
    run(
        &format!("pip install {}", args.join(" ")),
        Command::new(python)
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--disable-pip-version-check",
            ])
            .args(args)
            .current_dir(root())
            .env("MATURIN_PEP517_ARGS", "--profile dev"),
    )
}

#[test]
fn python_bindings_pass_their_tests() {
    let python = venv();
    pip(&python, &["-r", "python/requirements-test.txt"]);
    pip(&python, &["./python"]);
    let shared = root().join("..").join("shared");
    assert!(
        shared.join("scenes").is_dir(),
        "the test data is missing: {}/scenes",
        shared.display()
    );
    let out = run(
        "pytest python/tests",
        Command::new(&python)
            .args([
                "-m",
                "pytest",
                "-q",
                "-p",
                "no:cacheprovider",
                "python/tests",
            ])
            .current_dir(root())
            .env("OAVM_PACK", env!("CARGO_BIN_EXE_oavm-pack"))
            .env("OAVM_TRACE", env!("CARGO_BIN_EXE_oavm-trace"))
            .env("OAVM_SHARED", &shared),
    );
    eprintln!("{out}");
    // pytest fails when it collects nothing; a skip would pass it: neither may happen.
    assert!(
        out.contains(" passed") && !out.contains(" skipped"),
        "pytest ran no tests, or skipped some:\n{out}"
    );
}
