//! The OAVM paper's Table 3 rebuilt: frames a second of animations, each frame brought into the
//! file by a local update (`oavm::render::animate`, `Mode::Update`) or by a full pack
//! (`Mode::Rebuild`), and ray traced with the scene's lights, shadows, reflection and
//! refraction; and the cost of an update per frame step against a full pack.
//!
//!     cargo run --release --features tools --example anim_bench -- [--frames 10] [--sizes 1024x768,800x600,400x300]
//!         [--depth 5] [--out DIR] [--work DIR] [--steps-only] SCENE...
//!
//! A SCENE is `[NAME=]PATH[@FIRST]`: a BART scene (`.aff`, posed at each frame's time, the
//! camera on its camera path where it has one), or a directory of Rain frames (`tools/rain.rs`:
//! `DIR/rain.aff` and `DIR/rain_{}.ply`). `FIRST` is the first frame (default: the middle of a
//! BART scene's animation, where its objects move; 0 for Rain). For each scene the file is
//! packed at frame `FIRST` (updatable, its root cube holding frames `FIRST..=FIRST+N`: for
//! Rain the bounds of frame `FIRST` alone, since every frame spans the box `tools/rain.rs`
//! documents), then frames `FIRST+1..=FIRST+N` are rendered at each size twice: updated from a
//! copy of that file, and packed whole each frame with the same options and root cube (the
//! pack writes the primitive table too, so that both files are alike). The two must give the
//! same images (their digests are compared frame by frame). `--steps-only` renders 1x1 images
//! with no bounces, for the update cost alone (Rain at 10^7 balls).
//!
//! Writes `OUT/NAME.json` (every report, frame by frame; `--name`, default `anim_bench`) and
//! `OUT/NAME.md` (the two tables) after every scene, and prints the tables. A frame's time is its update (or pack), opening the file
//! and the render; posing the frame and writing images are not counted (none are written).
//! Run it at `nice -n 19` on an otherwise idle machine; the tables name the machine and commit.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Parser;
use oavm::Error;
use oavm::pack::PackOptions;
use oavm::render::animate::{
    AnimateOptions, Animation, AnimationReport, CameraChoice, FirstPack, Mode, animate,
};
use serde::Serialize;

#[path = "../src/bin/cli/mod.rs"]
mod cli;

#[derive(Parser, Debug)]
#[command(about = "Frames a second of animations by updates and by full rebuilds (Table 3)")]
struct Args {
    /// Scenes: `[NAME=]PATH[@FIRST]`, PATH a BART `.aff` or a directory of Rain frames.
    #[arg(required = true)]
    scenes: Vec<String>,
    /// Frames rendered per scene and size (after the one packed).
    #[arg(long, default_value_t = 10)]
    frames: u64,
    /// Image sizes.
    #[arg(long, value_delimiter = ',', value_parser = cli::parse_size,
          default_value = "1024x768,800x600,400x300")]
    sizes: Vec<(u32, u32)>,
    /// Bounces of reflection and refraction.
    #[arg(long, default_value_t = oavm::render::DEFAULT_MAX_DEPTH)]
    depth: u32,
    /// Only the update cost: render 1x1 images with no bounces.
    #[arg(long)]
    steps_only: bool,
    /// Where the JSON and markdown go.
    #[arg(long, default_value = "target/anim")]
    out: PathBuf,
    /// Where the .oavm files go (default: OUT/work).
    #[arg(long)]
    work: Option<PathBuf>,
    /// Pack every frame (the first and each full rebuild) streaming within this much memory
    /// (e.g. 8G; frames that are binary PLY files only), as `oavm-pack --mem-budget`. Without
    /// it a frame is streamed only when building it in memory would not fit in the memory
    /// available at that moment (`oavm-pack`'s rule), which can differ from frame to frame.
    #[arg(long, value_parser = cli::parse_bytes)]
    mem_budget: Option<u64>,
    /// Name of the outputs: OUT/NAME.json, OUT/NAME.md.
    #[arg(long, default_value = "anim_bench")]
    name: String,
}

/// A scene to measure.
struct SceneSpec {
    name: String,
    view: PathBuf,
    meshes: Option<String>,
    first: u64,
    /// Every frame spans the same box (Rain's, `tools/rain.rs`): the bounds of one frame are
    /// those of all, found without reading the others.
    same_box: bool,
}

fn parse_scene(text: &str) -> Result<SceneSpec, Error> {
    let (name, rest) = match text.split_once('=') {
        Some((n, r)) => (Some(n.to_owned()), r),
        None => (None, text),
    };
    let (path, first) = match rest.rsplit_once('@') {
        Some((p, f)) => (
            p,
            Some(f.parse::<u64>().map_err(|e| {
                Error::Invalid(format!("{text:?}: {f:?} is not a frame number: {e}"))
            })?),
        ),
        None => (rest, None),
    };
    let path = PathBuf::from(path);
    let stem = |p: &Path| {
        p.file_stem()
            .map_or("scene".into(), |s| s.to_string_lossy().into_owned())
    };
    if path.is_dir() {
        return Ok(SceneSpec {
            name: name.unwrap_or_else(|| stem(&path)),
            view: path.join("rain.aff"),
            meshes: Some(path.join("rain_{}.ply").display().to_string()),
            first: first.unwrap_or(0),
            same_box: true,
        });
    }
    let first = match first {
        Some(f) => f,
        None => oavm::mesh::load_aff(&path, None)?
            .animation
            .map_or(0, |(_, _, n)| n / 2),
    };
    Ok(SceneSpec {
        name: name.unwrap_or_else(|| stem(&path)),
        view: path,
        meshes: None,
        first,
        same_box: false,
    })
}

fn animation(s: &SceneSpec, frames: std::ops::Range<u64>) -> Result<Animation, Error> {
    match &s.meshes {
        Some(p) => Animation::with_meshes(&s.view, p, frames),
        None => Animation::new(&s.view, frames),
    }
}

/// One size of one scene: the frames by updates and by rebuilds.
#[derive(Serialize)]
struct Run {
    width: u32,
    height: u32,
    update: AnimationReport,
    rebuild: AnimationReport,
    /// Every frame's image the same, updated and rebuilt (by digest).
    images_identical: bool,
}

#[derive(Serialize)]
struct SceneResult {
    name: String,
    view: PathBuf,
    meshes: Option<String>,
    /// The frame packed; frames `first + 1 ..= first + frames` are rendered.
    first: u64,
    triangles: u64,
    first_pack: FirstPack,
    runs: Vec<Run>,
    /// The process's peak RSS after the scene (`VmHWM`, the whole run so far).
    peak_rss_bytes: Option<u64>,
}

#[derive(Serialize)]
struct Machine {
    cpu: String,
    cores: usize,
    memory_bytes: Option<u64>,
    commit: String,
    /// Uncommitted changes in the work tree when measured.
    dirty: bool,
    /// The 1-minute load average (`/proc/loadavg`) at the start and at the end: other work on
    /// the machine, which the timings include.
    load_average: [f64; 2],
}

#[derive(Serialize)]
struct Report {
    machine: Machine,
    frames: u64,
    depth: u32,
    steps_only: bool,
    scenes: Vec<SceneResult>,
    seconds: f64,
}

fn machine() -> Machine {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let cpu = cpuinfo
        .lines()
        .find_map(|l| l.strip_prefix("model name"))
        .map_or("unknown".into(), |l| {
            l.trim_start_matches([' ', '\t', ':']).to_owned()
        });
    let memory_bytes = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| {
            m.lines()
                .find_map(|l| l.strip_prefix("MemTotal:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        })
        .map(|kb| kb * 1024);
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .args(args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .ok()
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
    };
    Machine {
        cpu,
        cores: cli::cores(),
        memory_bytes,
        commit: git(&["rev-parse", "--short", "HEAD"]).unwrap_or_default(),
        dirty: git(&["status", "--porcelain", "--untracked-files=no"])
            .is_some_and(|s| !s.is_empty()),
        load_average: [load_average(); 2],
    }
}

/// The 1-minute load average (0 where `/proc/loadavg` cannot be read).
fn load_average() -> f64 {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|l| l.split_whitespace().next()?.parse().ok())
        .unwrap_or(0.0)
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    cli::main_with("anim_bench", || run(&args))
}

fn run(args: &Args) -> Result<(), Error> {
    let started = Instant::now();
    if args.frames == 0 {
        return Err(Error::Invalid("--frames must be at least 1".into()));
    }
    let specs: Vec<SceneSpec> = args
        .scenes
        .iter()
        .map(|s| parse_scene(s))
        .collect::<Result<_, _>>()?;
    let work = args.work.clone().unwrap_or_else(|| args.out.join("work"));
    std::fs::create_dir_all(&work).map_err(|e| Error::io(&work, e))?;
    std::fs::create_dir_all(&args.out).map_err(|e| Error::io(&args.out, e))?;
    let sizes = if args.steps_only {
        vec![(1, 1)]
    } else {
        args.sizes.clone()
    };
    let mut report = Report {
        machine: machine(),
        frames: args.frames,
        depth: args.depth,
        steps_only: args.steps_only,
        scenes: Vec::new(),
        seconds: 0.0,
    };
    for s in &specs {
        eprintln!("{}: packing frame {}", s.name, s.first);
        // Packed at FIRST with a root cube over FIRST..=FIRST+N; frames FIRST+1..=FIRST+N.
        let whole = animation(s, s.first..s.first + args.frames + 1)?;
        let anim = animation(s, s.first + 1..s.first + args.frames + 1)?;
        let packed = work.join(format!("{}.first.oavm", s.name));
        let pack = PackOptions {
            bounds: match s.same_box {
                true => Some(animation(s, s.first..s.first + 1)?.bounds()?),
                false => None,
            },
            mem_budget: args.mem_budget,
            ..PackOptions::default()
        };
        let first = whole.pack_first(&packed, &pack)?;
        let updated = work.join(format!("{}.updated.oavm", s.name));
        let rebuilt = work.join(format!("{}.rebuilt.oavm", s.name));
        let mut runs = Vec::new();
        for &(width, height) in &sizes {
            let opts = |mode| AnimateOptions {
                mode,
                width: Some(width),
                height: Some(height),
                max_depth: if args.steps_only { 0 } else { args.depth },
                camera: CameraChoice::Auto,
                pack: PackOptions {
                    bounds: Some(first.bounds),
                    mem_budget: args.mem_budget,
                    ..PackOptions::default()
                },
                ..AnimateOptions::default()
            };
            std::fs::copy(&packed, &updated).map_err(|e| Error::io(&updated, e))?;
            let progress = |what: &'static str| {
                let name = s.name.clone();
                move |f: &oavm::render::animate::FrameReport| {
                    eprintln!(
                        "{name} {width}x{height} {what} frame {}: {:.3} s + render {:.3} s",
                        f.frame, f.update_seconds, f.render_seconds
                    )
                }
            };
            let update = animate(
                &anim,
                &updated,
                &opts(Mode::Update),
                &mut progress("update"),
            )?;
            let rebuild = animate(&anim, &rebuilt, &opts(Mode::Rebuild), &mut progress("pack"))?;
            let images_identical = update
                .per_frame
                .iter()
                .zip(&rebuild.per_frame)
                .all(|(a, b)| a.image_xxh3 == b.image_xxh3);
            if !images_identical {
                eprintln!("{}: {width}x{height}: the images differ!", s.name);
            }
            runs.push(Run {
                width,
                height,
                update,
                rebuild,
                images_identical,
            });
        }
        for f in [&updated, &rebuilt] {
            let _ = std::fs::remove_file(f);
        }
        report.scenes.push(SceneResult {
            name: s.name.clone(),
            view: s.view.clone(),
            meshes: s.meshes.clone(),
            first: s.first,
            triangles: first.pack.stats.input_triangles,
            first_pack: first,
            runs,
            peak_rss_bytes: oavm::os::peak_rss_bytes(),
        });
        report.seconds = started.elapsed().as_secs_f64();
        report.machine.load_average[1] = load_average();
        // Written after every scene, so that a long run leaves what it measured.
        write(args, &report)?;
    }
    let md = markdown(&report);
    cli::print_text(&md)
}

fn write(args: &Args, report: &Report) -> Result<(), Error> {
    let json = serde_json::to_string_pretty(report)
        .map_err(|e| Error::Invalid(format!("cannot write the report as JSON: {e}")))?;
    let dir = &args.out;
    oavm::output::write_file(
        &dir.join(format!("{}.json", args.name)),
        json.as_bytes(),
        &[],
    )?;
    oavm::output::write_file(
        &dir.join(format!("{}.md", args.name)),
        markdown(report).as_bytes(),
        &[],
    )
}

/// The paper's frames a second (OAVM, CPU, textures, shadows and secondary rays; Yuan et al.
/// 2017, Table 3) at 1024x768, 800x600 and 400x300.
fn paper_fps(name: &str, width: u32) -> Option<f64> {
    let n = name.to_ascii_lowercase();
    let row = if n.contains("kitchen") {
        [3.1, 4.6, 11.8]
    } else if n.contains("robot") {
        [3.9, 5.3, 16.6]
    } else if n.contains("museum") {
        [5.6, 6.8, 20.6]
    } else if n.contains("rain") {
        [1.5, 2.3, 5.8]
    } else {
        return None;
    };
    match width {
        1024 => Some(row[0]),
        800 => Some(row[1]),
        400 => Some(row[2]),
        _ => None,
    }
}

fn ms(seconds: f64, frames: u64) -> f64 {
    1e3 * seconds / frames.max(1) as f64
}

fn mb(bytes: f64) -> String {
    format!("{:.2} MB", bytes / 1e6)
}

fn markdown(r: &Report) -> String {
    let m = &r.machine;
    let mut t = format!(
        "Measured on {} ({} cores, {:.1} GiB; load average {:.1} at the start, {:.1} at the \
         end), commit {}{}; {} frames a scene after the one packed, depth {}, threads: one per \
         core. A frame's time is the update (or full pack), \
         opening the file and the render; fps = frames / the sum of those.\n\n",
        m.cpu,
        m.cores,
        m.memory_bytes.unwrap_or(0) as f64 / (1u64 << 30) as f64,
        m.load_average[0],
        m.load_average[1],
        m.commit,
        if m.dirty {
            " (with uncommitted changes)"
        } else {
            ""
        },
        r.frames,
        r.depth
    );
    if !r.steps_only {
        t += "| scene | triangles | size | fps, updates | fps, rebuilds | paper fps | update ms/frame | \
              pack ms/frame | render ms/frame | Mrays/s | bytes written / update | file after updates | \
              same images |\n|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n";
        for s in &r.scenes {
            for run in &s.runs {
                let (u, b) = (&run.update, &run.rebuild);
                t += &format!(
                    "| {} | {} | {}x{} | {:.2} | {:.2} | {} | {:.1} | {:.1} | {:.1} | {:.2} | {} | {} | {} |\n",
                    s.name,
                    s.triangles,
                    run.width,
                    run.height,
                    u.fps,
                    b.fps,
                    paper_fps(&s.name, run.width).map_or("".into(), |f| format!("{f}")),
                    ms(u.update_seconds, u.frames),
                    ms(b.update_seconds, b.frames),
                    ms(u.render_seconds, u.frames),
                    u.mrays_per_s,
                    mb(u.bytes_written as f64 / u.frames.max(1) as f64),
                    mb(u.file_bytes as f64),
                    if run.images_identical {
                        "yes"
                    } else {
                        "**no**"
                    },
                );
            }
        }
        t += "\n";
    }
    t += "Update cost per frame step against a full pack (means over the frames of every run; \
          the file after the last update holds every generation written):\n\n\
          | scene | triangles | moved / frame | blocks rebuilt of total | update s | full pack s | \
          pack / update | bytes written / update | file packed | file after updates |\n\
          |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for s in &r.scenes {
        let (mut n, mut moved, mut rebuilt, mut total, mut upd, mut pack, mut bytes) =
            (0u64, 0u64, 0u64, 0u64, 0.0, 0.0, 0u64);
        let mut after = 0;
        for run in &s.runs {
            for f in &run.update.per_frame {
                n += 1;
                upd += f.update_seconds;
                bytes += f.bytes_written;
                if let Some(u) = &f.update {
                    moved += u.moved + u.inserted + u.removed;
                    rebuilt += u.blocks_rebuilt;
                    total += u.blocks_before;
                }
            }
            pack += run.rebuild.update_seconds;
            after = run.update.file_bytes;
        }
        let n = n.max(1);
        let mean_pack = pack / n as f64;
        let mean_upd = upd / n as f64;
        t += &format!(
            "| {} | {} | {} | {:.1} of {:.1} | {:.3} | {:.3} | {:.2}x | {} | {} | {} |\n",
            s.name,
            s.triangles,
            moved / n,
            rebuilt as f64 / n as f64,
            total as f64 / n as f64,
            mean_upd,
            mean_pack,
            if mean_upd > 0.0 {
                mean_pack / mean_upd
            } else {
                0.0
            },
            mb(bytes as f64 / n as f64),
            mb(s.first_pack.pack.file_bytes as f64),
            mb(after as f64),
        );
    }
    t
}
