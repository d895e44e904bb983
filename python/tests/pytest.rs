//! The Python package's tests (`python/tests`, pytest), run by `cargo test` at the top of the
//! workspace. Being this crate's test makes that `cargo test` build the extension (the cdylib
//! `_native`) with the rest, against the same `oavm` the library's tests use; this runner lays
//! the package out in a folder of its own (`python/oavm/` and the extension as
//! `oavm/_native.abi3.so`), makes a virtual environment under the target directory
//! (`target/python-venv`, with `python3 -m venv`, or `$OAVM_PYTHON -m venv`), installs what the
//! tests need (`python/requirements-test.txt`, pinned), and runs pytest on the package, with the
//! paths of this build's `oavm-pack` and `oavm-trace`, whose output files the answers must equal
//! byte for byte. Those two are the `oavm` package's binaries, which this crate cannot name: the
//! runner asks cargo for the workspace's test build first (`cargo test --no-run`, nothing to do
//! after a `cargo test` at the top; the whole build after `cargo test -p oavm-python`), so that
//! they are this source's. The way a user installs the package, `pip install ./python`
//! (maturin), is the ignored test below: it builds the crate a second time, with other features,
//! for about a minute.
//!
//! Nothing here is skipped: no Python, no network for a first install, or a failing pytest is
//! a failing test, with pip's or pytest's output.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The workspace's folder (this crate is `python/` in it).
fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("python/ has a parent")
        .to_path_buf()
}

/// The folder of this build's profile (`target/debug` for `cargo test`), where cargo put this
/// test (in `deps/`), the extension and the workspace's binaries.
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test's own path");
    exe.parent()
        .and_then(Path::parent)
        .unwrap_or_else(|| panic!("{}: not in target/PROFILE/deps", exe.display()))
        .to_path_buf()
}

/// The target directory (the profile folder's parent).
fn target_dir() -> PathBuf {
    profile_dir()
        .parent()
        .expect("the profile folder has a parent")
        .to_path_buf()
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
        eprintln!("pytest.rs: making {} with {base} {version}", venv.display());
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

/// Asks cargo for the workspace's test build (`cargo test --no-run` in this profile): nothing
/// to do after a `cargo test` at the top, and after `cargo test -p oavm-python` it builds the
/// `oavm` binaries the tests compare with, from this source.
fn workspace_build() {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    // The folder's name is the profile's, but for `test` (and `dev`), whose folder is `debug`.
    let profile = profile_dir();
    let name = profile
        .file_name()
        .expect("a profile folder")
        .to_string_lossy();
    let name = if name == "debug" { "test".into() } else { name };
    run(
        "cargo test --no-run (the workspace's binaries and this extension)",
        Command::new(cargo)
            .args(["test", "--no-run", "--quiet", "--profile", &name])
            .current_dir(root()),
    );
}

/// The package `oavm` laid out in a fresh folder: its Python half (`python/oavm/`) and the
/// extension this workspace's build made, as `oavm/_native.abi3.so`.
fn package() -> tempfile::TempDir {
    let profile = profile_dir();
    // Built for this test as a dependency, the extension stays in `deps/` (cargo copies up only
    // what a command names).
    let built = profile.join("deps").join("lib_native.so");
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

/// One of the `oavm` package's binaries, built by [`package`]'s `cargo test --no-run`.
fn binary(name: &str) -> PathBuf {
    let path = profile_dir().join(name);
    assert!(path.is_file(), "{} is missing", path.display());
    path
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
    .env("OAVM_PACK", binary("oavm-pack"))
    .env("OAVM_TRACE", binary("oavm-trace"))
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
    workspace_build();
    let pkg = package();
    // The package the tests import is this one, not one installed in the environment before.
    let found = run(
        "import oavm",
        Command::new(&python)
            .args(["-c", "import oavm; print(oavm.__file__)"])
            .current_dir(root())
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
    workspace_build();
    pytest(&python, None);
}
