//! Crash safety of updates (format-spec §2.1), measured: `oavm-update` killed with SIGKILL at
//! random moments, many times, and after each kill the file must open, verify, and answer every
//! ray exactly as either the previous frame or the new one (never anything else), an update
//! that finished before the kill must never be lost, and a reader that opened the file before
//! the update must still answer as the previous frame.
//!
//!     cargo build --release --features cli --bin oavm-update
//!     cargo run --release --features tools --example crash_updates -- [--kills N] [--seed S] [--json] SCENE...
//!
//! A SCENE is `FILE.aff@T0,T1` (a BART scene posed at T0, updated to T1) or `A.ply,B.ply` (two
//! meshes with the same primitive ids). For each, the first frame is packed `--updatable` (with
//! the root cube fitted to both frames); both frames are packed fresh for their answers (closest
//! hits' `t` bits and primitives, and any-hit answers, to random and primary rays). An
//! uninterrupted update is run three times (its median time and the bytes it appends are what
//! the kills aim at); then each of N kills (spread over the scenes) copies the packed file,
//! opens a reader on it, starts `oavm-update` on it, and sends SIGKILL at one of three kinds of
//! moment, in turn, so that every phase of an update is hit, whatever the machine's load:
//!
//! - **time**: a random time between 0 and 1.5 times the update's median (reading the mesh,
//!   finding the changes, rebuilding, or after it ended);
//! - **append**: when the file has grown by a random fraction of what the update appends
//!   (the file's length is polled): amid the blocks, the primitive chunks and the sections;
//! - **commit**: once the file has its final length, after a random 0-3 ms: the first sync,
//!   the header's write into the other slot, the second sync, or the exit;
//!
//! then checks the file and the reader. Every tenth kill is followed by an update run to
//! completion on the killed
//! file, which must answer as the new frame: a crash leaves a file that later updates work on.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use oavm::pack::{PackOptions, Quiet};
use oavm::rays::{self, Bounds, Camera};
use oavm::{Hit, Mesh, Ray, Scene};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

fn main() -> std::process::ExitCode {
    match run() {
        Ok(true) => std::process::ExitCode::SUCCESS,
        Ok(false) => std::process::ExitCode::from(2),
        Err(e) => {
            eprintln!("crash_updates: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// One scene: how to load each frame, and what `oavm-update` is given for the second.
struct Spec {
    name: String,
    load: Box<dyn Fn(bool) -> Result<Mesh>>,
    /// Arguments after the file: the mesh and, for AFF, `--time T1`.
    update_args: Vec<String>,
}

fn parse_spec(s: &str) -> Result<Spec> {
    if let Some((path, times)) = s.split_once('@') {
        let (a, b) = times
            .split_once(',')
            .ok_or_else(|| format!("{s:?}: expected FILE.aff@T0,T1"))?;
        let (t0, t1): (f64, f64) = (a.parse()?, b.parse()?);
        let p = PathBuf::from(path);
        let q = p.clone();
        Ok(Spec {
            name: format!("{}@{t0},{t1}", p.display()),
            load: Box::new(move |second| {
                Ok(oavm::mesh::load_at(&q, Some(if second { t1 } else { t0 }))?)
            }),
            update_args: vec![p.display().to_string(), "--time".into(), t1.to_string()],
        })
    } else {
        let (a, b) = s
            .split_once(',')
            .ok_or_else(|| format!("{s:?}: expected A.ply,B.ply or FILE.aff@T0,T1"))?;
        let (a, b) = (PathBuf::from(a), PathBuf::from(b));
        let (la, lb) = (a.clone(), b.clone());
        Ok(Spec {
            name: format!("{} -> {}", a.display(), b.display()),
            load: Box::new(move |second| Ok(oavm::mesh::load(if second { &lb } else { &la })?)),
            update_args: vec![b.display().to_string()],
        })
    }
}

/// A small deterministic generator (splitmix64).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A digest of the answers of `scene` to `rays`.
fn digest<D: AsRef<[u8]> + oavm::logical::BlockSource>(
    scene: &Scene<D>,
    rays: &[Ray],
) -> Result<u64> {
    let mut hits = vec![Hit::MISS; rays.len()];
    scene.intersect_batch(rays, &mut hits)?;
    let mut occ = vec![0u8; rays.len()];
    scene.occluded_batch(rays, &mut occ)?;
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    for (hit, o) in hits.iter().zip(&occ) {
        h.update(&hit.t.to_bits().to_le_bytes());
        h.update(&hit.prim.to_le_bytes());
        h.update(&[*o]);
    }
    Ok(h.digest())
}

/// What one scene's kills found.
#[derive(Default, serde::Serialize)]
struct Outcome {
    scene: String,
    triangles: u64,
    update_seconds: f64,
    /// Bytes an uninterrupted update appends (the file's growth).
    update_bytes: u64,
    kills: u64,
    /// Kills by kind of moment (time, append, commit), and of those the ones that found the
    /// update still running.
    kills_by_moment: [u64; 3],
    running_at_kill_by_moment: [u64; 3],
    /// Kills after which the file answered as the previous frame, or as the new one.
    previous: u64,
    new: u64,
    /// Of the new: the update had exited (finished) before the kill.
    finished_before_kill: u64,
    /// Files with bytes past their generation's end (an interrupted update's).
    trailing_bytes: u64,
    /// Updates run to completion on a killed file.
    resumed: u64,
    failures: Vec<String>,
}

fn run() -> Result<bool> {
    let mut kills = 500u64;
    let mut seed = 1u64;
    let mut json = false;
    let mut specs = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--kills" => kills = args.next().ok_or("--kills N")?.parse()?,
            "--seed" => seed = args.next().ok_or("--seed S")?.parse()?,
            "--json" => json = true,
            s if s.starts_with("--") => return Err(format!("unknown option {s}").into()),
            s => specs.push(parse_spec(s)?),
        }
    }
    if specs.is_empty() {
        return Err("give at least one SCENE (FILE.aff@T0,T1 or A.ply,B.ply)".into());
    }
    let exe = std::env::current_exe()?;
    let update_bin = exe
        .parent()
        .and_then(Path::parent)
        .map(|d| d.join("oavm-update"))
        .filter(|p| p.exists())
        .ok_or(
            "oavm-update is not built: cargo build --release --features cli --bin oavm-update",
        )?;
    let dir = tempfile::TempDir::new()?;
    let mut rng = Rng(seed);
    let mut outcomes = Vec::new();
    let per_scene = kills.div_ceil(specs.len() as u64);
    for spec in &specs {
        outcomes.push(scene(spec, per_scene, &update_bin, dir.path(), &mut rng)?);
    }
    let ok = outcomes.iter().all(|o| o.failures.is_empty());
    if json {
        println!("{}", serde_json::to_string_pretty(&outcomes)?);
    } else {
        for o in &outcomes {
            println!(
                "{}: {} triangles, update {:.3} s appending {} bytes; {} kills (time/append/commit: {:?}, update still running at {:?}): {} previous frame, {} new frame ({} had finished), {} with trailing bytes, {} resumed; {} failures",
                o.scene,
                o.triangles,
                o.update_seconds,
                o.update_bytes,
                o.kills,
                o.kills_by_moment,
                o.running_at_kill_by_moment,
                o.previous,
                o.new,
                o.finished_before_kill,
                o.trailing_bytes,
                o.resumed,
                o.failures.len()
            );
            for f in o.failures.iter().take(10) {
                println!("  FAILED: {f}");
            }
        }
    }
    Ok(ok)
}

fn scene(spec: &Spec, kills: u64, bin: &Path, dir: &Path, rng: &mut Rng) -> Result<Outcome> {
    let a = (spec.load)(false)?;
    let b = (spec.load)(true)?;
    let mut out = Outcome {
        scene: spec.name.clone(),
        triangles: a.triangles.len() as u64,
        ..Outcome::default()
    };
    // Root cube over both frames.
    let bb = Bounds::of_points(a.positions.iter().chain(&b.positions).copied());
    let base = dir.join("base.oavm");
    let opts = PackOptions {
        updatable: true,
        bounds: Some((bb.min, bb.max)),
        ..PackOptions::default()
    };
    oavm::pack::pack_mesh(a.clone(), "frame 0", &base, &opts, &Quiet)?;
    let fresh = |m: &Mesh, name: &str| -> Result<PathBuf> {
        let p = dir.join(name);
        oavm::pack::pack_mesh(m.clone(), name, &p, &PackOptions::default(), &Quiet)?;
        Ok(p)
    };
    let (fa, fb) = (fresh(&a, "a.oavm")?, fresh(&b, "b.oavm")?);
    let mut rays = rays::random_rays(&bb, 20_000, 5);
    rays.extend(Camera::framing(&bb).primary_rays(128, 96));
    let want_a = digest(&Scene::open(&fa)?, &rays)?;
    let want_b = digest(&Scene::open(&fb)?, &rays)?;
    if want_a == want_b {
        return Err(format!(
            "{}: both frames answer alike: nothing to tell apart",
            spec.name
        )
        .into());
    }
    if digest(&Scene::open(&base)?, &rays)? != want_a {
        return Err(format!(
            "{}: the packed first frame answers otherwise than a fresh pack",
            spec.name
        )
        .into());
    }
    drop((a, b));

    // An uninterrupted update, three times: its median time and the bytes it appends.
    let work = dir.join("work.oavm");
    let base_len = std::fs::metadata(&base)?.len();
    let mut times = Vec::new();
    for _ in 0..3 {
        std::fs::copy(&base, &work)?;
        let t0 = Instant::now();
        let st = Command::new(bin)
            .arg(&work)
            .args(&spec.update_args)
            .stdout(Stdio::null())
            .status()?;
        times.push(t0.elapsed().as_secs_f64());
        if !st.success() || digest(&Scene::open(&work)?, &rays)? != want_b {
            return Err(format!(
                "{}: an uninterrupted update failed or answered wrongly",
                spec.name
            )
            .into());
        }
    }
    times.sort_by(f64::total_cmp);
    out.update_seconds = times[1];
    let final_len = std::fs::metadata(&work)?.len();
    out.update_bytes = final_len.saturating_sub(base_len);

    let started = Instant::now();
    for k in 0..kills {
        std::fs::copy(&base, &work)?;
        // A reader of the previous generation, open across the update.
        let reader = Scene::open(&work)?;
        let moment = (k % 3) as usize;
        let (frac, pause) = (rng.unit(), rng.unit());
        let t0 = Instant::now();
        let mut child = Command::new(bin)
            .arg(&work)
            .args(&spec.update_args)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()?;
        let len = || std::fs::metadata(&work).map_or(0, |m| m.len());
        match moment {
            0 => std::thread::sleep(Duration::from_secs_f64(frac * 1.5 * out.update_seconds)),
            _ => {
                let target = match moment {
                    1 => base_len + ((frac * out.update_bytes as f64) as u64).max(1),
                    _ => final_len,
                };
                // Poll the length until the target or the update's end (a minute at most: an
                // update that hangs is a failure below, not a hang of this tool).
                while len() < target
                    && child.try_wait()?.is_none()
                    && t0.elapsed() < Duration::from_secs(60)
                {
                    std::thread::sleep(Duration::from_micros(50));
                }
                if moment == 2 {
                    std::thread::sleep(Duration::from_secs_f64(pause * 0.003));
                }
            }
        }
        let wait = t0.elapsed();
        let running = child.try_wait()?.is_none();
        let finished = matches!(child.try_wait()?, Some(s) if s.success());
        let _ = child.kill();
        child.wait()?;
        out.kills_by_moment[moment] += 1;
        out.running_at_kill_by_moment[moment] += u64::from(running);
        out.kills += 1;
        let kinds = ["time", "append", "commit"];
        let mut fail = |what: String| {
            out.failures
                .push(format!("kill {k} ({}) at {wait:?}: {what}", kinds[moment]))
        };
        match Scene::open(&work) {
            Err(e) => fail(format!("does not open: {e}")),
            Ok(s) => {
                match s.verify() {
                    Ok(r) if r.is_ok() => {}
                    Ok(r) => fail(format!("verify: {:?}", r.defects)),
                    Err(e) => fail(format!("verify: {e}")),
                }
                let h = *s.file().header();
                if (h.file_size as usize) < s.file().bytes().len() {
                    out.trailing_bytes += 1;
                }
                match digest(&s, &rays) {
                    Ok(d) if d == want_a && h.generation == 1 => {
                        if finished {
                            fail("the update had finished, the file answers as before it".into());
                        }
                        out.previous += 1;
                    }
                    Ok(d) if d == want_b && h.generation == 2 => {
                        out.new += 1;
                        out.finished_before_kill += u64::from(finished);
                    }
                    Ok(_) => fail(format!(
                        "generation {} answers as neither frame",
                        h.generation
                    )),
                    Err(e) => fail(format!("tracing: {e}")),
                }
            }
        }
        match digest(&reader, &rays) {
            Ok(d) if d == want_a => {}
            Ok(_) => fail("the reader opened before the update answers otherwise".into()),
            Err(e) => fail(format!("the reader opened before the update: {e}")),
        }
        drop(reader);
        if k % 10 == 9 {
            let st = Command::new(bin)
                .arg(&work)
                .args(&spec.update_args)
                .stdout(Stdio::null())
                .status()?;
            let ok = st.success()
                && Scene::open(&work)
                    .map_err(|e| e.to_string())
                    .and_then(|s| digest(&s, &rays).map_err(|e| e.to_string()))
                    .is_ok_and(|d| d == want_b);
            if !ok {
                fail("an update after the kill failed or answered wrongly".into());
            }
            out.resumed += 1;
            eprintln!(
                "{}: {} kills, {} failures ({:.0} s)",
                spec.name,
                k + 1,
                out.failures.len(),
                started.elapsed().as_secs_f64()
            );
        }
    }
    Ok(out)
}
