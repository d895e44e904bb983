//! The Python bindings' tests (`python/tests`, pytest), run by `cargo test`. The extension
//! (`oavm-python`, a workspace member) is built by the same `cargo test` as the library, with
//! the same dependencies; this test makes sure it is built (`cargo build --profile test`, which
//! finds it fresh after a `cargo test` and builds it after a `cargo test --test integration`),
//! lays the package out in a folder of its own (`python/oavm/` and the extension as
//! `oavm/_native.abi3.so`), makes a virtual environment under the target directory
//! (`target/python-venv`, with `python3 -m venv`, or `$OAVM_PYTHON -m venv`), installs what the
//! tests need (`python/requirements-test.txt`, pinned), and runs pytest on the package, with the
//! paths of this build's `oavm-pack` and `oavm-trace`, whose output files the answers must equal
//! byte for byte. The way a user installs it, `pip install ./python` (maturin), is the ignored
//! test below: it builds the crate a second time, with other features, for about a minute.
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

/// The package `oavm` laid out in a fresh folder: its Python half (`python/oavm/`) and the
/// extension this workspace's build made, as `oavm/_native.abi3.so`.
fn package() -> tempfile::TempDir {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    run(
        "cargo build --profile test (the extension)",
        Command::new(cargo)
            .args(["build", "--profile", "test", "--quiet", "--lib"])
            .current_dir(root()),
    );
    let built = target_dir().join("debug").join("lib_native.so");
    assert!(
        built.is_file(),
        "the extension is missing: {}",
        built.display()
    );
    let dir = tempfile::tempdir().expect("a temporary folder");
    let pkg = dir.path().join("oavm");
    std::fs::create_dir(&pkg).expect("the package folder");
    for e in std::fs::read_dir(root().join("python/oavm")).expect("python/oavm") {
        let p = e.expect("an entry").path();
        if p.is_file()
            && p.extension()
                .is_some_and(|x| x == "py" || x == "pyi" || x == "typed")
        {
            std::fs::copy(&p, pkg.join(p.file_name().unwrap())).expect("copy the package");
        }
    }
    std::fs::copy(&built, pkg.join("_native.abi3.so")).expect("copy the extension");
    dir
}

/// Runs pytest on `python/tests` with `python`, the package found on `pythonpath` if given
/// (else as installed), and requires that it ran tests and skipped none.
fn pytest(python: &Path, pythonpath: Option<&Path>) {
    let shared = root().join("..").join("shared");
    assert!(
        shared.join("scenes").is_dir(),
        "the test data is missing: {}/scenes",
        shared.display()
    );
    let mut cmd = Command::new(python);
    cmd.args([
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
    .env("OAVM_SHARED", &shared);
    if let Some(p) = pythonpath {
        cmd.env("PYTHONPATH", p);
    }
    let out = run("pytest python/tests", &mut cmd);
    eprintln!("{out}");
    // pytest fails when it collects nothing; a skip would pass it: neither may happen.
    assert!(
        out.contains(" passed") && !out.contains(" skipped"),
        "pytest ran no tests, or skipped some:\n{out}"
    );
}

#[test]
fn python_bindings_pass_their_tests() {
    let python = venv();
    pip(&python, &["-r", "python/requirements-test.txt"]);
    let pkg = package();
    // The package the tests import is this one, not one installed in the environment before.
    let found = run(
        "import oavm",
        Command::new(&python)
            .args(["-c", "import oavm; print(oavm.__file__)"])
            .env("PYTHONPATH", pkg.path()),
    );
    assert!(
        found.trim().starts_with(&*pkg.path().to_string_lossy()),
        "{found}"
    );
    pytest(&python, Some(pkg.path()));
}

/// What a user runs: `pip install ./python` (maturin builds the extension), then the same tests.
#[test]
#[ignore = "builds the bindings a second time through maturin (about a minute)"]
fn python_package_installs_with_pip_and_passes_its_tests() {
    let python = venv();
    pip(&python, &["-r", "python/requirements-test.txt"]);
    pip(&python, &["./python"]);
    pytest(&python, None);
}
