//! Correctness check: OAVM's answers against independent references, ray by ray.
//!
//! ```text
//! cargo run --release --features tools --example check -- [--scene NAME=PATH]... [--random N]
//!     [--width W --height H] [--brute N] [--seed S] [--examples N]
//!     [--leaf-size K] [--max-depth D] [--no-merge] [--json]
//! ```
//!
//! For each scene (default: the bunny and the dragon from `../shared/scenes`) it packs the mesh in
//! memory (default `BuildOptions`, or the ones given), opens the bytes as a [`Scene`] and traces
//! three ray sets:
//!
//! - `random`: `--random` rays (default 10^6) from `oavm::rays::random_rays`, closest hit;
//! - `primary`: one ray per pixel of a `--width` x `--height` image (default 1024x768) from
//!   `Camera::framing`, closest hit;
//! - `shadow`: from every primary hit *OAVM* found toward `default_light`
//!   (`oavm::rays::shadow_rays`), any hit.
//!
//! Each set is compared with two references that share no traversal code with OAVM:
//!
//! - brute force in f64 (`oavm::geom::reference`: Möller–Trumbore over every triangle, sharing no
//!   code with OAVM's f32 watertight test) on a strided subset, every `k`-th ray with
//!   `k = floor(rays / N)`, so at least `N = --brute` rays (default 10^4 for meshes up to 200,000
//!   triangles, such as the bunny, and 2,000 above, such as the dragon: brute force costs rays x
//!   triangles; `--brute 0` skips it). A disagreement on a ray that grazes an edge or a corner
//!   (`reference::grazes`: where a watertight f32 test and the f64 one may both be right) is
//!   counted apart (`grazing`) and does not fail; any other fails the check;
//! - obvhs (a CWBVH with its own Möller–Trumbore test, `tools/peers/mod.rs`) on every ray.
//!
//! Two answers agree as `../shared/RAYS.md` defines it: both miss, or both hit with
//! `|t1 - t2| <= 1e-4 * L`, `L` the diagonal of the mesh's bounding box (any-hit answers: the same
//! answer). The comparison with obvhs passes when at least 99.99 % of the rays agree, i.e. at
//! most `floor(compared / 10^4)` disagree (obvhs's triangle test is not watertight); the one with
//! the f64 brute force when none disagrees off grazing rays. On the random set OAVM's closest hit and any hit (same
//! segment) must also agree with each other on every ray: they share the triangle test and the
//! traversal, so any difference is a bug, not rounding.
//!
//! Where both sides hit, the share with the same primitive id is printed for information (a ray
//! through a shared edge or vertex may be given either triangle). The first `--examples`
//! disagreements of each comparison (default 5) are printed with the ray, both answers, the closest
//! hit by brute force with OAVM's f32 triangle test and by brute force in f64 (Möller–Trumbore on
//! the f32 inputs, so it shares no arithmetic with either tracer), and where the ray meets each triangle involved (smallest
//! barycentric coordinate in f64: ~0 on an edge, negative just outside; |cos| between ray and
//! normal: ~0 grazing; and what obvhs's triangle test alone answers). Up to 1,000 disagreements with obvhs per comparison are judged by both
//! brute forces: which side each agrees with.
//!
//! Output: one line per scene, set and reference, or one JSON object with every number (`--json`;
//! progress goes to stderr either way). Exits 1 if any comparison fails, 2 on a usage or input
//! error.

#[path = "peers/mod.rs"]
mod peers;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use oavm::geom::reference;
use oavm::geom::triangle::RayShear;
use oavm::rays::{Bounds, Camera, default_light, random_rays, shadow_rays};
use oavm::{BuildOptions, Hit, Mesh, Ray, Scene};
use peers::ObvhsScene;
use rayon::prelude::*;
use serde_json::{Value, json};

/// Share of compared rays that must agree.
const REQUIRED: f64 = 0.9999;
/// Largest `t` difference, relative to the bounding-box diagonal, that still agrees.
const TOLERANCE: f64 = oavm::geom::AGREEMENT_TOLERANCE;
/// Default brute-force subset per set: rays for meshes up to [`LARGE_MESH`] triangles, and above.
const BRUTE_SMALL_MESH: usize = 10_000;
const BRUTE_LARGE_MESH: usize = 2_000;
const LARGE_MESH: usize = 200_000;
/// Disagreements with obvhs that brute force judges, per comparison.
const JUDGED: usize = 1_000;

const USAGE: &str = "usage: check [--scene NAME=PATH]... [--random N] [--width W --height H] \
[--brute N] [--seed S] [--examples N] [--leaf-size K] [--max-depth D] [--no-merge] [--json]";

/// The validated configuration.
struct Config {
    scenes: Vec<(String, PathBuf)>,
    random: usize,
    width: u32,
    height: u32,
    /// Brute-force rays per set; `None`: by mesh size.
    brute: Option<usize>,
    seed: u64,
    examples: usize,
    json: bool,
    opts: BuildOptions,
}

fn main() -> ExitCode {
    let config = match parse_args(std::env::args().skip(1)) {
        Ok(Some(c)) => c,
        Ok(None) => {
            println!("{USAGE}");
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("check: {e}\n{USAGE}");
            return ExitCode::from(2);
        }
    };
    match run(&config) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => {
            eprintln!("check: FAILED (see the lines marked FAIL)");
            ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!("check: {e}");
            ExitCode::from(2)
        }
    }
}

fn parse_args(args: impl Iterator<Item = String>) -> Result<Option<Config>, String> {
    let mut c = Config {
        scenes: Vec::new(),
        random: 1_000_000,
        width: 1024,
        height: 768,
        brute: None,
        seed: 1,
        examples: 5,
        json: false,
        opts: BuildOptions::default(),
    };
    fn num<T: std::str::FromStr>(flag: &str, v: Option<String>) -> Result<T, String> {
        let v = v.ok_or_else(|| format!("{flag} needs a value"))?;
        v.parse()
            .map_err(|_| format!("{flag} {v}: not a non-negative integer"))
    }
    let mut it = args;
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "-h" | "--help" => return Ok(None),
            "--scene" => {
                let v = it.next().ok_or("--scene needs NAME=PATH")?;
                let (name, path) = match v.split_once('=') {
                    Some((n, p)) => (n.to_string(), PathBuf::from(p)),
                    None => {
                        let p = PathBuf::from(&v);
                        let stem = p
                            .file_stem()
                            .map_or("scene".into(), |s| s.to_string_lossy().into_owned());
                        (stem, p)
                    }
                };
                c.scenes.push((name, path));
            }
            "--random" => c.random = num(&arg, it.next())?,
            "--width" => c.width = num(&arg, it.next())?,
            "--height" => c.height = num(&arg, it.next())?,
            "--brute" => c.brute = Some(num(&arg, it.next())?),
            "--seed" => c.seed = num(&arg, it.next())?,
            "--examples" => c.examples = num(&arg, it.next())?,
            "--leaf-size" => c.opts.leaf_size = num(&arg, it.next())?,
            "--max-depth" => c.opts.max_depth = num(&arg, it.next())?,
            "--no-merge" => c.opts.merge = false,
            "--json" => c.json = true,
            other => return Err(format!("unknown argument {other}")),
        }
    }
    c.opts.validate().map_err(|e| e.to_string())?;
    if c.scenes.is_empty() {
        // Relative to the crate, so the tool runs from any directory through cargo.
        let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes");
        c.scenes
            .push(("bunny".into(), shared.join("bunny/bun_zipper.ply")));
        c.scenes
            .push(("dragon".into(), shared.join("dragon/dragon_vrip.ply")));
    }
    Ok(Some(c))
}

// ---------------------------------------------------------------------------------------------
// Answers
// ---------------------------------------------------------------------------------------------

/// One kind of answer (closest hit or any hit), from each of the three tracers.
trait Answer: Copy + PartialEq + Send + Sync {
    const QUERY: &'static str;
    fn oavm<D: AsRef<[u8]> + oavm::logical::BlockSource>(
        scene: &Scene<D>,
        rays: &[Ray],
    ) -> Result<Vec<Self>, String>;
    /// Brute force with OAVM's own f32 watertight test ([`kernel_closest`]), for judging
    /// disagreements with obvhs (is it the triangle test or the traversal?).
    fn brute(tris: &[[[f32; 3]; 3]], ray: &Ray) -> Self;
    /// Brute force in f64 (`geom::reference`): shares no code with OAVM; the reference of the
    /// strided comparison, and a judge of disagreements with obvhs.
    fn exact(tris: &[[[f32; 3]; 3]], ray: &Ray) -> Self;
    fn obvhs(scene: &ObvhsScene, ray: &Ray) -> Self;
    fn is_hit(self) -> bool;
    /// The triangle hit, for closest-hit answers.
    fn prim(self) -> Option<u32>;
    /// The agreement rule of `RAYS.md` ([`Hit::agrees`]); `diag` is `L`.
    fn agrees(self, other: Self, diag: f64) -> bool;
    fn json(self) -> Value;
}

impl Answer for Hit {
    const QUERY: &'static str = "closest";
    fn oavm<D: AsRef<[u8]> + oavm::logical::BlockSource>(
        scene: &Scene<D>,
        rays: &[Ray],
    ) -> Result<Vec<Hit>, String> {
        let mut out = vec![Hit::MISS; rays.len()];
        scene
            .intersect_batch(rays, &mut out)
            .map_err(|e| e.to_string())?;
        Ok(out)
    }
    fn brute(tris: &[[[f32; 3]; 3]], ray: &Ray) -> Hit {
        kernel_closest(tris, ray)
    }
    fn exact(tris: &[[[f32; 3]; 3]], ray: &Ray) -> Hit {
        reference::closest(tris, ray)
    }
    fn obvhs(scene: &ObvhsScene, ray: &Ray) -> Hit {
        scene.intersect(ray)
    }
    fn is_hit(self) -> bool {
        Hit::is_hit(&self)
    }
    fn prim(self) -> Option<u32> {
        self.is_hit().then_some(self.prim)
    }
    fn agrees(self, other: Hit, diag: f64) -> bool {
        Hit::agrees(&self, &other, diag)
    }
    fn json(self) -> Value {
        if self.is_hit() {
            json!({ "t": self.t, "prim": self.prim })
        } else {
            json!("miss")
        }
    }
}

impl Answer for bool {
    const QUERY: &'static str = "any";
    fn oavm<D: AsRef<[u8]> + oavm::logical::BlockSource>(
        scene: &Scene<D>,
        rays: &[Ray],
    ) -> Result<Vec<bool>, String> {
        let mut out = vec![0u8; rays.len()];
        scene
            .occluded_batch(rays, &mut out)
            .map_err(|e| e.to_string())?;
        Ok(out.into_iter().map(|o| o == 1).collect())
    }
    fn brute(tris: &[[[f32; 3]; 3]], ray: &Ray) -> bool {
        kernel_closest(tris, ray).is_hit()
    }
    fn exact(tris: &[[[f32; 3]; 3]], ray: &Ray) -> bool {
        reference::occluded(tris, ray)
    }
    fn obvhs(scene: &ObvhsScene, ray: &Ray) -> bool {
        scene.occluded(ray)
    }
    fn is_hit(self) -> bool {
        self
    }
    fn prim(self) -> Option<u32> {
        None
    }
    fn agrees(self, other: bool, _diag: f64) -> bool {
        self == other
    }
    fn json(self) -> Value {
        json!(if self { "occluded" } else { "clear" })
    }
}

fn text(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Object(o) => format!("t={} prim={}", o["t"], o["prim"]),
        other => other.to_string(),
    }
}

// ---------------------------------------------------------------------------------------------
// Comparisons
// ---------------------------------------------------------------------------------------------

/// One reference compared with OAVM on one set.
struct Comparison {
    reference: &'static str,
    stride: usize,
    compared: usize,
    disagreements: usize,
    /// Disagreements on rays that graze an edge or a corner (`reference::grazes`), where both
    /// sides may be right: not counted in `disagreements` (only the f64 reference excuses them).
    grazing: usize,
    /// Closest hit: rays on which both hit and agree, and of those, with the same primitive id.
    both_hit: usize,
    same_prim: usize,
    /// Disagreements with obvhs judged by brute force with OAVM's triangle test, then by brute
    /// force in f64: (judged, the judge agrees with OAVM, with obvhs, with neither) for each.
    verdicts: Option<[[usize; 4]; 2]>,
    /// Whether a single disagreement fails (internal consistency) rather than 0.01 %.
    strict: bool,
    examples: Vec<Value>,
    seconds: f64,
}

impl Comparison {
    fn allowed(&self) -> usize {
        if self.strict {
            0
        } else {
            ((1.0 - REQUIRED) * self.compared as f64 + 1e-9).floor() as usize
        }
    }
    fn pass(&self) -> bool {
        self.disagreements <= self.allowed()
    }
    /// Agreement in percent, rounded down (100 only when nothing disagrees).
    fn agreement_percent(&self) -> f64 {
        if self.compared == 0 {
            return 100.0;
        }
        let share = (self.compared - self.disagreements) as f64 / self.compared as f64;
        (share * 1e6).floor() / 1e4
    }
    fn json(&self) -> Value {
        json!({
            "reference": self.reference,
            "stride": self.stride,
            "compared": self.compared,
            "disagreements": self.disagreements,
            "grazing": self.grazing,
            "allowed_disagreements": self.allowed(),
            "agreement_percent": self.agreement_percent(),
            "pass": self.pass(),
            "both_hit": self.both_hit,
            "same_prim": self.same_prim,
            "judged": self.verdicts.map(|v| v.map(|[n, o, r, x]| json!({
                "judged": n, "judge_agrees_with_oavm": o, "judge_agrees_with_reference": r,
                "judge_agrees_with_neither": x }))).map(|[brute, exact]| json!({
                "brute_force": brute, "f64_brute_force": exact })),
            "examples": self.examples,
            "seconds": self.seconds,
        })
    }
}

/// What the tools know about one scene while checking it.
struct Ctx<'a, D> {
    mesh: &'a Mesh,
    /// The mesh's triangles by primitive id, for the brute forces.
    tris: &'a [[[f32; 3]; 3]],
    scene: &'a Scene<D>,
    obvhs: &'a ObvhsScene,
    /// `L`, the diagonal of the mesh's bounding box.
    diag: f64,
    brute: usize,
    examples: usize,
}

/// `k` such that every `k`-th ray of `len` gives at least `want` rays (all of them if fewer).
fn stride_for(len: usize, want: usize) -> usize {
    (len / want.max(1)).max(1)
}

/// Compares `ours[i]` with `theirs[j]` for the pairs `(i, j)` of `pairs`.
fn compare<A: Answer>(
    ctx: &Ctx<'_, impl AsRef<[u8]> + oavm::logical::BlockSource>,
    rays: &[Ray],
    ours: &[A],
    pairs: impl Iterator<Item = (usize, A)>,
    reference: &'static str,
    stride: usize,
    excuse_grazing: bool,
) -> Comparison {
    let mut c = Comparison {
        reference,
        stride,
        compared: 0,
        disagreements: 0,
        grazing: 0,
        both_hit: 0,
        same_prim: 0,
        verdicts: None,
        strict: false,
        examples: Vec::new(),
        seconds: 0.0,
    };
    for (i, theirs) in pairs {
        c.compared += 1;
        let o = ours[i];
        if o.agrees(theirs, ctx.diag) {
            if let (Some(p), Some(q)) = (o.prim(), theirs.prim()) {
                c.both_hit += 1;
                c.same_prim += usize::from(p == q);
            }
        } else if excuse_grazing && reference::grazes(ctx.tris, &rays[i]) {
            c.grazing += 1;
        } else {
            c.disagreements += 1;
            if c.examples.len() < ctx.examples {
                c.examples
                    .push(example(ctx, i, &rays[i], o.json(), theirs.json()));
            }
        }
    }
    c
}

/// A disagreement, described for diagnosis: the ray, both answers, brute force's closest hit in
/// the ray's segment and where the ray meets each triangle involved.
fn example(
    ctx: &Ctx<'_, impl AsRef<[u8]>>,
    i: usize,
    ray: &Ray,
    ours: Value,
    theirs: Value,
) -> Value {
    let truth = kernel_closest(ctx.tris, ray);
    let exact = reference::closest(ctx.tris, ray);
    let mut prims: Vec<u32> = [&ours, &theirs]
        .iter()
        .filter_map(|v| v.get("prim").and_then(Value::as_u64).map(|p| p as u32))
        .collect();
    prims.extend([truth, exact].iter().filter(|h| h.is_hit()).map(|h| h.prim));
    prims.sort_unstable();
    prims.dedup();
    let triangles: Vec<Value> = prims
        .iter()
        .map(|&p| {
            let (bary, cos) = where_ray_meets(ctx.tris, ray, p as usize);
            let obvhs_t = obvhs_triangle_test(ctx.mesh, ray, p as usize);
            json!({ "prim": p, "min_barycentric": bary, "abs_cos": cos,
                    "obvhs_triangle_test": obvhs_t.map_or(json!("miss"), |t| json!(t)) })
        })
        .collect();
    json!({
        "ray": i,
        "origin": ray.origin.map(number), "dir": ray.dir.map(number),
        "tmin": number(ray.tmin), "tmax": number(ray.tmax),
        "oavm": ours, "reference": theirs,
        "brute_closest": truth.json(), "f64_closest": exact.json(),
        "triangles": triangles,
    })
}

/// obvhs's own triangle test (`Triangle::intersect`, as `ObvhsScene` calls it) on one triangle:
/// tells a hit lost by obvhs's f32 arithmetic from one lost by its traversal.
fn obvhs_triangle_test(mesh: &Mesh, ray: &Ray, prim: usize) -> Option<f32> {
    let [v0, v1, v2] = mesh.triangle(prim).map(glam::Vec3A::from);
    let tri = obvhs::triangle::Triangle { v0, v1, v2 };
    let t = tri.intersect(&obvhs::ray::Ray {
        origin: ray.origin.into(),
        direction: ray.dir.into(),
        inv_direction: glam::Vec3A::ZERO,
        tmin: ray.tmin,
        tmax: ray.tmax,
    });
    (t != f32::INFINITY).then_some(t)
}

/// `x` as JSON, with non-finite values as strings (`"inf"`) rather than JSON's `null`.
fn number(x: f32) -> Value {
    if x.is_finite() {
        json!(x)
    } else {
        json!(x.to_string())
    }
}

/// Brute force with OAVM's own watertight f32 test (the kernel every structure shares): closest
/// hit over every triangle, ties to the lowest id. A second judge beside the f64 reference:
/// where the two differ, the kernel's rounding decided.
fn kernel_closest(tris: &[[[f32; 3]; 3]], ray: &Ray) -> Hit {
    if !ray.is_valid() {
        return Hit::MISS;
    }
    let shear = RayShear::new(ray);
    let mut best = Hit::MISS;
    for (i, tri) in tris.iter().enumerate() {
        if let Some(t) = shear.intersect(tri, ray.tmin, best.t.min(ray.tmax))
            && (!best.is_hit() || t < best.t)
        {
            best = Hit { t, prim: i as u32 };
        }
    }
    best
}

/// Where the line of `ray` meets triangle `prim`, in f64: the smallest barycentric coordinate
/// (0 on an edge, negative just outside) and `|cos|` of the angle between the ray and the normal
/// (0 for a grazing ray).
fn where_ray_meets(tris: &[[[f32; 3]; 3]], ray: &Ray, prim: usize) -> (f64, f64) {
    let [a, b, c] = tris[prim].map(|p| glam::DVec3::from(p.map(f64::from)));
    let d = glam::DVec3::from(ray.dir.map(f64::from));
    let n = (b - a).cross(c - a);
    let cos = n.dot(d).abs() / (n.length() * d.length());
    let margin = reference::meet(&tris[prim], ray).map_or(f64::NEG_INFINITY, |m| m.margin());
    (margin, cos)
}

/// The results of one ray set.
struct SetReport {
    name: &'static str,
    query: &'static str,
    rays: usize,
    hits: usize,
    comparisons: Vec<Comparison>,
}

/// Traces `rays` with OAVM and compares with brute force (strided subset) and obvhs (every ray).
fn check_set<A: Answer>(
    ctx: &Ctx<'_, impl AsRef<[u8]> + oavm::logical::BlockSource>,
    name: &'static str,
    rays: &[Ray],
) -> Result<(SetReport, Vec<A>), String> {
    let ours = A::oavm(ctx.scene, rays)?;

    let t = Instant::now();
    // `--brute 0` skips brute force (stride 0: no ray).
    let (stride, subset): (usize, Vec<usize>) = match ctx.brute {
        0 => (0, Vec::new()),
        n => {
            let k = stride_for(rays.len(), n);
            (k, (0..rays.len()).step_by(k).collect())
        }
    };
    let truth: Vec<A> = subset
        .par_iter()
        .map(|&i| A::exact(ctx.tris, &rays[i]))
        .collect();
    let mut vs_brute = compare(
        ctx,
        rays,
        &ours,
        subset.iter().copied().zip(truth.iter().copied()),
        "f64 brute",
        stride,
        true,
    );
    // Off grazing rays, the f64 reference is the truth: one disagreement fails.
    vs_brute.strict = true;
    vs_brute.seconds = t.elapsed().as_secs_f64();
    eprintln!(
        "  {name}: f64 brute force on {} rays: {:.1} s",
        subset.len(),
        vs_brute.seconds
    );

    let t = Instant::now();
    let theirs: Vec<A> = rays.par_iter().map(|r| A::obvhs(ctx.obvhs, r)).collect();
    let mut vs_obvhs = compare(
        ctx,
        rays,
        &ours,
        theirs.iter().copied().enumerate(),
        "obvhs",
        1,
        false,
    );
    // Who is right where they differ: brute force on (up to JUDGED of) those rays, with OAVM's
    // watertight test and in f64.
    let differing: Vec<usize> = (0..rays.len())
        .filter(|&i| !ours[i].agrees(theirs[i], ctx.diag))
        .take(JUDGED)
        .collect();
    if !differing.is_empty() {
        let verdicts = differing
            .par_iter()
            .map(|&i| {
                [A::brute(ctx.tris, &rays[i]), A::exact(ctx.tris, &rays[i])].map(|judge| {
                    match (
                        judge.agrees(ours[i], ctx.diag),
                        judge.agrees(theirs[i], ctx.diag),
                    ) {
                        (true, _) => [1, 1, 0, 0],
                        (false, true) => [1, 0, 1, 0],
                        (false, false) => [1, 0, 0, 1],
                    }
                })
            })
            .reduce(
                || [[0; 4]; 2],
                |a, b| std::array::from_fn(|j| std::array::from_fn(|k| a[j][k] + b[j][k])),
            );
        vs_obvhs.verdicts = Some(verdicts);
    }
    vs_obvhs.seconds = t.elapsed().as_secs_f64();

    let report = SetReport {
        name,
        query: A::QUERY,
        rays: rays.len(),
        hits: ours.iter().filter(|a| a.is_hit()).count(),
        comparisons: vec![vs_brute, vs_obvhs],
    };
    Ok((report, ours))
}

// ---------------------------------------------------------------------------------------------
// Scenes
// ---------------------------------------------------------------------------------------------

struct SceneReport {
    name: String,
    path: PathBuf,
    triangles: usize,
    diagonal: f64,
    oavm_nodes: u64,
    build_seconds: [f64; 2],
    sets: Vec<SetReport>,
}

fn check_scene(config: &Config, name: &str, path: &Path) -> Result<SceneReport, String> {
    let mesh = oavm::mesh::load(path).map_err(|e| e.to_string())?;
    let bounds = Bounds::of_points(mesh.positions.iter().copied());
    let diagonal = bounds.diagonal();
    eprintln!(
        "{name}: {} ({} triangles, L = {diagonal:.6})",
        path.display(),
        mesh.triangles.len()
    );

    let t = Instant::now();
    let (parts, stats) =
        oavm::pack::build(&mesh, &config.opts, &oavm::pack::Quiet).map_err(|e| e.to_string())?;
    let bytes = oavm::pack::encode(&parts).expect("encode");
    let scene = Scene::from_bytes(bytes, format!("{name}.oavm")).map_err(|e| e.to_string())?;
    let oavm_build = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let obvhs = ObvhsScene::build(&mesh.positions, &mesh.triangles);
    let obvhs_build = t.elapsed().as_secs_f64();
    eprintln!(
        "  build: oavm {oavm_build:.2} s ({} nodes), obvhs {obvhs_build:.2} s",
        stats.nodes
    );

    let brute = config
        .brute
        .unwrap_or(if mesh.triangles.len() <= LARGE_MESH {
            BRUTE_SMALL_MESH
        } else {
            BRUTE_LARGE_MESH
        });
    let tris = mesh.corners();
    let ctx = Ctx {
        mesh: &mesh,
        tris: &tris,
        scene: &scene,
        obvhs: &obvhs,
        diag: diagonal,
        brute,
        examples: config.examples,
    };

    let random = random_rays(&bounds, config.random, config.seed);
    let (mut random_report, closest) = check_set::<Hit>(&ctx, "random", &random)?;
    // Closest hit and any hit of OAVM on the same rays.
    let t = Instant::now();
    let any = bool::oavm(&scene, &random)?;
    let mut consistency = compare(
        &ctx,
        &random,
        &closest.iter().map(|h| h.is_hit()).collect::<Vec<_>>(),
        any.iter().copied().enumerate(),
        "oavm any-hit",
        1,
        false,
    );
    consistency.strict = true;
    consistency.seconds = t.elapsed().as_secs_f64();
    random_report.comparisons.push(consistency);

    let primary = Camera::framing(&bounds).primary_rays(config.width, config.height);
    let (primary_report, primary_hits) = check_set::<Hit>(&ctx, "primary", &primary)?;
    let shadow = shadow_rays(&primary, &primary_hits, default_light(&bounds));
    let (shadow_report, _) = check_set::<bool>(&ctx, "shadow", &shadow)?;

    Ok(SceneReport {
        name: name.to_string(),
        path: path.to_owned(),
        triangles: mesh.triangles.len(),
        diagonal,
        oavm_nodes: stats.nodes,
        build_seconds: [oavm_build, obvhs_build],
        sets: vec![random_report, primary_report, shadow_report],
    })
}

fn run(config: &Config) -> Result<bool, String> {
    let start = Instant::now();
    let mut scenes = Vec::new();
    for (name, path) in &config.scenes {
        scenes.push(check_scene(config, name, path)?);
    }
    let pass = scenes
        .iter()
        .flat_map(|s| &s.sets)
        .flat_map(|s| &s.comparisons)
        .all(Comparison::pass);
    let seconds = start.elapsed().as_secs_f64();
    if config.json {
        print_json(config, &scenes, pass, seconds);
    } else {
        print_table(config, &scenes, pass, seconds);
    }
    Ok(pass)
}

fn print_table(config: &Config, scenes: &[SceneReport], pass: bool, seconds: f64) {
    println!(
        "oavm check: agree = both miss, or both hit with |t1 - t2| <= {TOLERANCE:e} L (any hit: same answer); \
         pass: f64 brute force, every ray off grazing ones; obvhs, >= {:.2} %; closest/any consistency, every ray",
        REQUIRED * 100.0
    );
    println!(
        "build options: leaf size {}, max depth {}, merge {}; {} random rays (seed {}), {}x{} camera; {} rayon threads",
        config.opts.leaf_size,
        config.opts.max_depth,
        config.opts.merge,
        config.random,
        config.seed,
        config.width,
        config.height,
        rayon::current_num_threads()
    );
    for s in scenes {
        println!(
            "\n{}: {} | {} triangles | L = {:.6}, tolerance {:.3e} | build oavm {:.2} s ({} nodes), obvhs {:.2} s",
            s.name,
            s.path.display(),
            s.triangles,
            s.diagonal,
            TOLERANCE * s.diagonal,
            s.build_seconds[0],
            s.oavm_nodes,
            s.build_seconds[1]
        );
        println!(
            "{:<8} {:<7} {:>8} {:>8}  {:<12} {:>6} {:>8} {:>8} {:>7} {:>9}  {:<6} {:>9}  {:>6}",
            "set",
            "query",
            "rays",
            "hits",
            "reference",
            "stride",
            "compared",
            "disagree",
            "grazing",
            "agree %",
            "result",
            "same prim",
            "time"
        );
        for set in &s.sets {
            for c in &set.comparisons {
                let same_prim = if c.both_hit > 0 {
                    format!("{:.3} %", 100.0 * c.same_prim as f64 / c.both_hit as f64)
                } else {
                    "-".into()
                };
                println!(
                    "{:<8} {:<7} {:>8} {:>8}  {:<12} {:>6} {:>8} {:>8} {:>7} {:>9.4}  {:<6} {:>9}  {:>5.1}s",
                    set.name,
                    if c.reference == "oavm any-hit" {
                        "both"
                    } else {
                        set.query
                    },
                    set.rays,
                    set.hits,
                    c.reference,
                    c.stride,
                    c.compared,
                    c.disagreements,
                    c.grazing,
                    c.agreement_percent(),
                    if c.pass() { "PASS" } else { "FAIL" },
                    same_prim,
                    c.seconds
                );
            }
        }
        for set in &s.sets {
            for c in &set.comparisons {
                if let Some([[n, o, r, x], [_, eo, er, ex]]) = c.verdicts {
                    println!(
                        "  {} vs {}: {n} of {} disagreements judged; brute force sides with oavm {o}, with {} {r}, \
                         neither {x}; f64 brute force: oavm {eo}, {} {er}, neither {ex}",
                        set.name, c.reference, c.disagreements, c.reference, c.reference
                    );
                }
                for e in &c.examples {
                    print_example(set.name, c.reference, e);
                }
            }
        }
    }
    println!(
        "\n{} in {seconds:.1} s",
        if pass {
            "PASS: no disagreement with the f64 brute force off grazing rays, at least 99.99 % agreement with obvhs"
        } else {
            "FAIL: a disagreement with the f64 brute force off grazing rays, or below 99.99 % with obvhs"
        }
    );
}

fn print_example(set: &str, reference: &str, e: &Value) {
    let f = |k: &str| e[k].to_string().replace('"', "");
    println!(
        "  {set} ray {}: origin {} dir {} t in [{}, {}]: oavm {}, {reference} {}, brute {}, f64 {}",
        e["ray"],
        f("origin"),
        f("dir"),
        f("tmin"),
        f("tmax"),
        text(&e["oavm"]),
        text(&e["reference"]),
        text(&e["brute_closest"]),
        text(&e["f64_closest"])
    );
    if let Some(tris) = e["triangles"].as_array() {
        for t in tris {
            println!(
                "      prim {}: smallest barycentric {:.3e}, |cos(ray, normal)| {:.3e}, obvhs's triangle test {}",
                t["prim"],
                t["min_barycentric"].as_f64().unwrap_or(f64::NAN),
                t["abs_cos"].as_f64().unwrap_or(f64::NAN),
                t["obvhs_triangle_test"].to_string().replace('"', "")
            );
        }
    }
}

fn print_json(config: &Config, scenes: &[SceneReport], pass: bool, seconds: f64) {
    let scenes: Vec<Value> = scenes
        .iter()
        .map(|s| {
            json!({
                "name": s.name,
                "path": s.path,
                "triangles": s.triangles,
                "diagonal": s.diagonal,
                "tolerance": TOLERANCE * s.diagonal,
                "oavm_nodes": s.oavm_nodes,
                "build_seconds": { "oavm": s.build_seconds[0], "obvhs": s.build_seconds[1] },
                "sets": s.sets.iter().map(|set| json!({
                    "set": set.name,
                    "query": set.query,
                    "rays": set.rays,
                    "hits": set.hits,
                    "comparisons": set.comparisons.iter().map(Comparison::json).collect::<Vec<_>>(),
                })).collect::<Vec<_>>(),
            })
        })
        .collect();
    let out = json!({
        "options": config.opts,
        "random_rays": config.random,
        "seed": config.seed,
        "width": config.width,
        "height": config.height,
        "required_agreement": REQUIRED,
        "relative_tolerance": TOLERANCE,
        "threads": rayon::current_num_threads(),
        "scenes": scenes,
        "pass": pass,
        "seconds": seconds,
    });
    println!("{}", serde_json::to_string_pretty(&out).unwrap_or_default());
}
