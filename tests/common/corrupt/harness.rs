//! Opening, verifying and tracing a corrupted file, under a time limit; what a targeted
//! corruption must give; a test run in a child process.

use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::{Mutex, Once, OnceLock, mpsc};
use std::time::Duration;

use oavm::logical::{BlockReads, SceneOptions};
use oavm::physical::AlignedBytes;
use oavm::{Hit, Scene};

use super::*;

/// What happened to one corrupted file.
#[derive(Debug)]
pub enum Verdict {
    /// Open failed with this error.
    Rejected(String),
    /// Open succeeded, as `generation` (§2.1: the fixture's, or, with its newest header slot
    /// damaged, the one before). Tracing (unverified) gave `traced` (compared with the answers
    /// of that generation), and under a budget of a few blocks on 2 threads `tight` (if asked
    /// for); `verify` reported `defects`; `Err` holds a panic, with its message and place.
    Opened {
        generation: u64,
        traced: Result<Traced, String>,
        tight: Option<Result<Traced, String>>,
        defects: Result<Vec<String>, String>,
    },
}

#[derive(Debug, PartialEq)]
pub enum Traced {
    /// Bit for bit the intact file's answers (those of the generation it opened as).
    Same,
    /// Other answers (the first difference).
    Different(String),
    /// An error from either batch.
    Error(String),
}

impl Traced {
    /// Whether `self` and `other` are the same outcome (errors may name different places: the
    /// rays run in another order).
    pub fn same_outcome(&self, other: &Traced) -> bool {
        match (self, other) {
            (Traced::Error(_), Traced::Error(_)) => true,
            (a, b) => a == b,
        }
    }
}

/// A rayon pool of 2 threads, for the traces under a tight budget.
pub fn pool2() -> &'static rayon::ThreadPool {
    static P: OnceLock<rayon::ThreadPool> = OnceLock::new();
    P.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .expect("pool")
    })
}

/// Scene options for the smallest budget that lets 2 threads trace: five blocks (two a thread
/// and one more).
pub fn tight_options(fix: &Fixture) -> SceneOptions {
    SceneOptions {
        walk: fix.walk,
        mem_budget: Some(5 * fix.held),
        threads: 2,
        check_blocks: true,
        block_reads: BlockReads::Auto,
    }
}

/// Opens `bytes`; if that works, traces the fixture's rays through it without verifying it
/// (and, if `with_tight`, again under a tight budget on 2 threads), then verifies it.
pub fn evaluate(fix: &Fixture, bytes: &[u8], with_tight: bool) -> Verdict {
    let scene = match open_walking(bytes, fix.walk) {
        Ok(s) => s,
        Err(e) => return Verdict::Rejected(e.to_string()),
    };
    let traced = catching(|| trace(fix, &scene));
    let tight = with_tight.then(|| {
        catching(|| {
            let data = AlignedBytes::from_slice(bytes);
            let scene =
                Scene::from_bytes_with(data, "corrupt.oavm", &tight_options(fix)).expect("opens");
            pool2().install(|| trace(fix, &scene))
        })
    });
    let defects = catching(|| {
        scene
            .verify()
            .map(|r| r.defects)
            .unwrap_or_else(|e| vec![e.to_string()])
    });
    Verdict::Opened {
        generation: scene.file().header().generation,
        traced,
        tight,
        defects,
    }
}

/// Traces the fixture's rays through `scene` and compares the answers with the intact file's
/// answers of the generation `scene` holds (§2.1).
pub fn trace(fix: &Fixture, scene: &Scene<AlignedBytes>) -> Traced {
    let mut hits = vec![Hit::MISS; fix.rays.len()];
    let closest = scene.intersect_batch(&fix.rays, &mut hits);
    let mut occluded = vec![0u8; fix.rays.len()];
    let any = scene.occluded_batch(&fix.rays, &mut occluded);
    if let Err(e) = closest.and(any) {
        return Traced::Error(e.to_string());
    }
    let (want_hits, want_occluded) = fix.answers(scene.file().header().generation);
    let same = |a: &Hit, b: &Hit| a.t.to_bits() == b.t.to_bits() && a.prim == b.prim;
    if let Some(i) = (0..hits.len()).find(|&i| !same(&hits[i], &want_hits[i])) {
        return Traced::Different(format!(
            "ray {i}: {:?}, intact file {:?}",
            hits[i], want_hits[i]
        ));
    }
    if let Some(i) = (0..hits.len()).find(|&i| occluded[i] != want_occluded[i]) {
        return Traced::Different(format!(
            "ray {i}: occluded {}, intact file {}",
            occluded[i], want_occluded[i]
        ));
    }
    Traced::Same
}

/// Panics seen by the hook, with their place (a caught panic's payload has none, and rayon
/// re-raises a worker's panic on the caller): for the reports of [`catching`].
pub static PANICS: Mutex<Vec<String>> = Mutex::new(Vec::new());

/// Runs `f`, turning a panic into `Err("PANIC message [panicked at place]")`.
pub fn catching<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if let Ok(mut p) = PANICS.lock() {
                p.push(info.to_string().replace('\n', " "));
            }
            previous(info);
        }));
    });
    let before = PANICS.lock().map_or(0, |p| p.len());
    catch_unwind(AssertUnwindSafe(f)).map_err(|payload| {
        let msg = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "(no message)".into());
        // Several rayon workers may panic; the payload is one of theirs: find its place.
        let place = PANICS
            .lock()
            .ok()
            .and_then(|p| {
                let seen = p.get(before..)?;
                seen.iter()
                    .rev()
                    .find(|e| e.ends_with(msg.as_str()))
                    .cloned()
            })
            .unwrap_or_default();
        format!("PANIC {msg:?} [{place}]")
    })
}

/// Longest a corrupted file may take to open, trace and verify. The intact files take a few
/// milliseconds; a walk bounded as spec §10 says stays far below this.
pub const LIMIT: Duration = Duration::from_secs(20);

/// Runs `f` on a thread of its own and waits for it at most [`LIMIT`]. A panic comes back as
/// `Err` (see [`catching`]); a run that does not finish fails the test at once, naming `what`
/// (the thread is left behind: it cannot be stopped, and ends with the test process).
pub fn guarded<T: Send + 'static>(
    what: &dyn Fn() -> String,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T, String> {
    let (tx, rx) = mpsc::channel();
    std::thread::Builder::new()
        .name("corrupt-file".into())
        .spawn(move || {
            let _ = tx.send(catching(f));
        })
        .expect("spawn");
    match rx.recv_timeout(LIMIT) {
        Ok(r) => r,
        Err(_) => panic!(
            "HANG: {} did not open, trace and verify within {LIMIT:?}",
            what()
        ),
    }
}

/// [`evaluate`] under [`guarded`].
pub fn evaluate_guarded(
    fix: &'static Fixture,
    bytes: Vec<u8>,
    with_tight: bool,
    what: &str,
) -> Result<Verdict, String> {
    if std::env::var_os("OAVM_CORRUPTION_LOG").is_some() {
        eprintln!("case: {what}");
    }
    let w = what.to_string();
    guarded(&|| w.clone(), move || evaluate(fix, &bytes, with_tight))
}

/// Failures grouped by kind, so that one bug met a hundred times reads as one line and examples.
#[derive(Default)]
pub struct Failures(pub BTreeMap<String, Vec<String>>);

impl Failures {
    pub fn add(&mut self, kind: String, example: String) {
        self.0.entry(kind).or_default().push(example);
    }

    pub fn count(&self) -> usize {
        self.0.values().map(Vec::len).sum()
    }

    pub fn report(&self) -> String {
        let mut out = String::new();
        for (kind, list) in &self.0 {
            out += &format!("\n{} x {kind}; e.g.\n", list.len());
            for e in list.iter().take(3) {
                out += &format!("    {e}\n");
            }
        }
        out
    }
}

/// The kind of a panic report: its message and place, without the values.
pub fn panic_kind(stage: &str, panic: &str) -> String {
    let place = panic
        .split(" [")
        .nth(1)
        .and_then(|p| p.split(": ").next())
        .unwrap_or(panic);
    let msg = panic.split(" [").next().unwrap_or(panic);
    format!("{stage}: {msg} {place}")
}

/// Whether the pager checks a directory entry's `triangles` (§8.2) when it admits the block:
/// in a file of lists it repeats the block header's `triangle_count`; in a file of clusters it
/// is the sum of the block's groups' lanes in use, which the header does not hold, and which
/// only a pass over every group could check. The pager does not make it (§11: admission is
/// `O(levels)`, and without block checks only the pages a walk touches are read); the tracer
/// never reads the field; `verify` sums the lanes and reports the difference.
pub fn triangles_checked_by_pager(fix: &Fixture) -> bool {
    !fix.clusters
}

/// What one targeted corruption must give: verify must report a defect containing `defect`
/// ("block N": naming block N); tracing must not panic or hang, and if `trace_fails_on` lists
/// blocks, fail with an error naming one of them (unbounded and under a tight budget on 2
/// threads).
pub fn expect_caught(
    fix: &'static Fixture,
    what: String,
    bytes: Vec<u8>,
    defect: &str,
    trace_fails_on: &[usize],
    problems: &mut Vec<String>,
) {
    let reported = |d: &str| match defect.strip_prefix("block ").map(str::parse::<usize>) {
        Some(Ok(b)) => names_block(d, b),
        _ => d.contains(defect),
    };
    expect_reported(
        fix,
        what,
        bytes,
        defect,
        &reported,
        trace_fails_on,
        problems,
    );
}

/// [`expect_caught`] with the defect verify must report told by `reported` (described by
/// `defect`).
pub fn expect_reported(
    fix: &'static Fixture,
    what: String,
    bytes: Vec<u8>,
    defect: &str,
    reported: &dyn Fn(&str) -> bool,
    trace_fails_on: &[usize],
    problems: &mut Vec<String>,
) {
    let verdict = evaluate_guarded(fix, bytes, true, &what);
    let (generation, traced, tight, defects) = match verdict {
        Err(panic) => return problems.push(format!("{what}: {panic}")),
        Ok(Verdict::Rejected(e)) => return problems.push(format!("{what}: open failed: {e}")),
        Ok(Verdict::Opened {
            generation,
            traced,
            tight,
            defects,
        }) => (generation, traced, tight, defects),
    };
    if generation != fix.generation {
        problems.push(format!(
            "{what}: opened as generation {generation}, not the file's {}",
            fix.generation
        ));
    }
    for (stage, t) in [("trace", traced), ("tight trace", tight.expect("asked"))] {
        match t {
            Err(panic) => problems.push(format!("{what}: {stage}: {panic}")),
            _ if trace_fails_on.is_empty() => {}
            Ok(Traced::Error(e)) if trace_fails_on.iter().any(|&b| names_block(&e, b)) => {}
            Ok(t) => problems.push(format!(
                "{what}: {stage}: should fail naming block {trace_fails_on:?}: {t:?}"
            )),
        }
    }
    match defects {
        Err(panic) => problems.push(format!("{what}: verify: {panic}")),
        Ok(d) if d.iter().any(|d| reported(d)) => {}
        Ok(d) => problems.push(format!("{what}: verify should report {defect:?}: {d:?}")),
    }
}

/// Runs `f` in a child process (this test binary, running only `test`), so that an abort (a
/// failed allocation cannot be caught) fails the test instead of ending the whole run.
pub fn in_child_process(test: &str, f: impl FnOnce()) {
    if std::env::var_os("OAVM_CORRUPTION_CHILD").is_some() {
        f();
        return;
    }
    let exe = std::env::current_exe().expect("the test binary");
    let out = std::process::Command::new(exe)
        .args([test, "--exact", "--include-ignored", "--nocapture"])
        .env("OAVM_CORRUPTION_CHILD", "1")
        .output()
        .expect("run the test binary");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let key = |l: &&str| {
        ["memory allocation", "panicked", "HANG", "PANIC"]
            .iter()
            .any(|k| l.contains(k))
    };
    let tail: Vec<&str> = stderr.lines().filter(key).take(6).collect();
    assert!(
        out.status.success(),
        "{test}: the child process failed ({}):\n{}",
        out.status,
        tail.join("\n")
    );
}
