//! `oavm-trace FILE.oavm`: traces rays through a packed file, memory-mapped, with no rebuild.
//! Renders an image by default; traces ray files in batch mode, or rays it makes itself in
//! benchmark mode; verifies files; renders the frames of an animation. Glue: the arguments
//! become a typed [`Mode`], the library does the work (the shot of a render,
//! `oavm::render::Shot`; the benchmark's frame, `oavm::logical::FrameFigures`; the animation,
//! `oavm::render::animate`), this prints what it reports.

mod cli;

use std::fmt::Display;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::Parser;
use cli::Pool;
use oavm::logical::{FrameOptions, PageReport, Query, RaySet, TraceRun, Verification};
use oavm::output::Output;
use oavm::rays;
use oavm::render::animate::{self, AnimateOptions, Animation, AnimationRun, CameraChoice};
use oavm::render::{self, RenderReport, RenderTotal, ShadedReport, ShadedShot, Shot, ShotSpec};
use oavm::{Error, Scene};
use serde::Serialize;

/// Traces rays through an .oavm file made by oavm-pack.
///
/// With no mode option, renders the model from a camera that frames it (or from the viewpoint of
/// a BART scene, --view), shaded by a point light with shadows, and writes a PNG (with --shade,
/// ray traced with the scene's materials and lights, reflections and refractions). With --rays and
/// --hits (closest hit) or --occluded (any hit), traces a ray file in the formats of RAYS.md.
/// With --random N or --primary WxH (and --shadow), traces rays it makes and reports the figures
/// only. With --verify, checks every byte of the file. With --frames A..B, renders frames of an
/// animation (--view), bringing the file to each frame by a local update (or, with --rebuild, a
/// full pack), ray traced as with --shade, to numbered PNGs in the -o directory. Outputs are written atomically, through
/// symlinks, never over a directory, device or FIFO, nor over an input.
#[derive(Parser, Debug)]
#[command(name = "oavm-trace", version)]
struct Args {
    /// The .oavm file.
    file: PathBuf,
    /// Batch mode: a RAYS file to trace.
    #[arg(long, value_name = "RAYS", conflicts_with_all = ["random", "primary", "verify"])]
    rays: Option<PathBuf>,
    /// Batch mode: write closest hits to this HITS file.
    #[arg(
        long,
        value_name = "HITS",
        requires = "rays",
        conflicts_with = "occluded"
    )]
    hits: Option<PathBuf>,
    /// Batch mode: write any-hit answers to this OCCL file.
    #[arg(long, value_name = "OCCL", requires = "rays")]
    occluded: Option<PathBuf>,
    /// Benchmark mode: trace N random rays (origins around the model, directions uniform; the
    /// ray sets of `cargo run --example rays`), closest hit; nothing is written. At most what
    /// half of the available memory holds (64 bytes a ray).
    #[arg(long, value_name = "N", conflicts_with_all = ["primary", "verify"])]
    random: Option<u64>,
    /// Benchmark mode: trace the WxH primary rays of the camera (as for rendering: --eye,
    /// --target, --fov, --view...), closest hit; nothing is written.
    #[arg(long, value_name = "WxH", value_parser = cli::parse_size, conflicts_with = "verify")]
    primary: Option<(u32, u32)>,
    /// Benchmark mode: then trace a shadow ray (any hit) from every hit to the light.
    #[arg(long)]
    shadow: bool,
    /// Benchmark mode with --shadow: trace in waves of N rays, taken in the tracing order
    /// (--order), each wave's shadow rays right after its primary ones, while the blocks they
    /// start in are still in memory, as a renderer would (0: all primary rays, then all shadow
    /// rays; default 65536). The answers are the same.
    #[arg(long, value_name = "N", requires = "shadow")]
    wave: Option<usize>,
    /// Seed of --random (default 1).
    #[arg(long, requires = "random")]
    seed: Option<u64>,
    /// Check every section, checksum and invariant; exit non-zero on any defect.
    #[arg(long)]
    verify: bool,
    /// Render mode: the image to write (default: the file's name with .png). With --frames:
    /// the directory the frames go to (`frame_00012.png`; created if missing).
    #[arg(short, long, value_name = "PNG", conflicts_with_all = ["rays", "random", "primary", "verify"])]
    output: Option<PathBuf>,
    /// Render mode: image width (default 1024, or the --view scene's resolution).
    #[arg(long, conflicts_with_all = ["rays", "random", "primary", "verify"])]
    width: Option<u32>,
    /// Render mode: image height (default 768, or the --view scene's resolution).
    #[arg(long, conflicts_with_all = ["rays", "random", "primary", "verify"])]
    height: Option<u32>,
    /// Render mode: ray trace in Whitted's way with the materials and lights of the --view
    /// scene (a white diffuse material and one light for another mesh): shadows from every
    /// light, Phong highlights, reflection and refraction (see `oavm::render::render_shaded`).
    /// --light replaces the scene's lights by one white light.
    #[arg(long, conflicts_with_all = ["rays", "random", "primary", "verify"])]
    shade: bool,
    /// Render mode with --shade or --frames: the most bounces of reflection and refraction
    /// (default 5, at most 16; 0: none).
    #[arg(long, value_name = "N")]
    depth: Option<u32>,
    /// With --view: pose the scene at this time (default: its animation start, as oavm-pack
    /// does) for its camera, lights and materials. Give the time the file was packed at.
    #[arg(long, value_name = "T", requires = "view", conflicts_with = "frames")]
    time: Option<f64>,
    /// Animation mode: render frames A..B (A to B-1; A..=B; or one frame A) of the --view
    /// scene's animation (`a start end frames`: frame f at start + f (end - start) / frames):
    /// for each frame, bring FILE to its triangles by a local update (FILE must be packed with
    /// `oavm-pack --updatable`, its root cube holding every frame: see --pack), ray trace it as
    /// --shade does (the frame's lights and materials, shadows, reflection and refraction to
    /// --depth) and write OUT_DIR/frame_NNNNN.png (-o, required). The camera is the --view
    /// scene's `v` block, or its camera path with --camera-path.
    #[arg(long, value_name = "A..B", value_parser = animate::parse_frames, requires = "view",
          conflicts_with_all = ["rays", "random", "primary", "verify"])]
    frames: Option<std::ops::Range<u64>>,
    /// With --frames: read frame f's triangles from PATTERN, its {} replaced by f padded to
    /// five digits (e.g. DIR/rain_{}.ply of `cargo run --example rain`), triangle i being
    /// primitive i, instead of posing the --view scene, which gives the camera, lights and
    /// materials.
    #[arg(long, value_name = "PATTERN", requires = "frames")]
    frame_meshes: Option<String>,
    /// With --frames: pack each frame whole into FILE (replacing it) instead of updating it:
    /// the full rebuild per frame, to compare with. The images are the same, byte for byte.
    #[arg(long, requires = "frames")]
    rebuild: bool,
    /// With --frames: first pack FILE (replacing it) from frame A, updatable, with a root cube
    /// that holds every frame of the range (each frame posed to find its bounds).
    #[arg(long, requires = "frames", conflicts_with = "rebuild")]
    pack: bool,
    #[command(flatten)]
    camera: cli::CameraArgs,
    #[command(flatten)]
    trace: cli::TraceArgs,
    /// Print one JSON object with the figures of the run.
    #[arg(long)]
    json: bool,
}

/// What a run does, from the arguments.
#[derive(Debug)]
enum Mode {
    Render {
        image: PathBuf,
    },
    Batch {
        rays: PathBuf,
        query: Query,
        out: PathBuf,
    },
    Bench {
        set: RaySet,
        shadow: bool,
        wave: usize,
    },
    Verify,
    Frames {
        out_dir: PathBuf,
        range: std::ops::Range<u64>,
    },
}

/// Rays per wave by default (`--wave`).
const DEFAULT_WAVE: usize = 65536;

impl Args {
    /// An option given where its mode is not (clap's `requires` does not fire when the mode's
    /// own option is refused by a conflict of its own): a usage error, never ignored.
    fn misplaced(&self) -> Option<String> {
        let bench = self.random.is_some() || self.primary.is_some();
        let frames = self.frames.is_some();
        // Each group of options, given without what it needs (in the order checked)...
        let given = [
            (self.hits.is_some() || self.occluded.is_some()) && self.rays.is_none(),
            self.seed.is_some() && self.random.is_none(),
            (self.shadow || self.wave.is_some()) && !bench,
            self.depth.is_some() && !self.shade && !frames,
            frames && self.output.is_none(),
            (self.frame_meshes.is_some() || self.rebuild || self.pack) && !frames,
            self.time.is_some() && self.camera.view.is_none(),
        ];
        // ...and what it needs.
        const NEEDS: [(&str, &str); 7] = [
            ("--hits/--occluded", "--rays (batch mode)"),
            ("--seed", "--random N"),
            ("--shadow/--wave", "--random N or --primary WxH"),
            ("--depth", "--shade or --frames"),
            (
                "--frames",
                "-o OUT_DIR (the directory of the frames' images)",
            ),
            ("--frame-meshes/--rebuild/--pack", "--frames A..B"),
            ("--time", "--view SCENE.aff"),
        ];
        let (_, (name, needs)) = given.into_iter().zip(NEEDS).find(|g| g.0)?;
        Some(format!("{name} needs {needs}; it was given without"))
    }

    /// The mode the arguments ask for (clap has already refused the combinations that ask for
    /// two).
    fn mode(&self) -> Result<Mode, Error> {
        if self.verify {
            return Ok(Mode::Verify);
        }
        if let Some(range) = &self.frames {
            let out_dir = self.output.clone().ok_or_else(|| {
                Error::Invalid(
                    "--frames needs -o OUT_DIR, the directory the frames' images go to".into(),
                )
            })?;
            let range = range.clone();
            return Ok(Mode::Frames { out_dir, range });
        }
        if let Some(rays) = self.rays.clone() {
            let (query, out) = match (&self.hits, &self.occluded) {
                (Some(h), None) => (Query::Closest, h.clone()),
                (None, Some(o)) => (Query::Any, o.clone()),
                _ => {
                    return Err(Error::Invalid(
                        "--rays needs --hits (closest hit) or --occluded (any hit)".into(),
                    ));
                }
            };
            return Ok(Mode::Batch { rays, query, out });
        }
        let set = match (self.random, self.primary) {
            (Some(count), _) => RaySet::Random {
                count,
                seed: self.seed.unwrap_or(1),
            },
            (None, Some((width, height))) => RaySet::Primary { width, height },
            (None, None) if self.shadow => {
                return Err(Error::Invalid(
                    "--shadow needs --random N or --primary WxH".into(),
                ));
            }
            (None, None) => {
                let image = self.output.clone();
                let image = image.unwrap_or_else(|| self.file.with_extension("png"));
                return Ok(Mode::Render { image });
            }
        };
        let (shadow, wave) = (self.shadow, self.wave.unwrap_or(DEFAULT_WAVE));
        Ok(Mode::Bench { set, shadow, wave })
    }
}

fn main() -> ExitCode {
    let start = Instant::now();
    let args = Args::parse();
    if let Some(msg) = args.misplaced() {
        use clap::CommandFactory;
        Args::command()
            .error(clap::error::ErrorKind::ArgumentConflict, msg)
            .exit();
    }
    cli::main_with("oavm-trace", || run(&args, start))
}

fn run(args: &Args, start: Instant) -> Result<(), Error> {
    let mode = args.mode()?;
    match mode {
        Mode::Verify => return verify(args),
        Mode::Frames { out_dir, range } => return frames(args, &out_dir, range),
        _ => {}
    }
    let t = Instant::now();
    let opts = args.trace.scene_options(Pool::AfterOpen);
    let mut scene = Scene::open_with(&args.file, &opts)?;
    let open_ms = t.elapsed().as_secs_f64() * 1e3;
    // Streamed batches draw their rays done and blocks read (on a terminal, after a second).
    scene.set_progress(Some(std::sync::Arc::new(cli::progress_bar())));
    let threads = args.trace.threads_after_open(&scene, "oavm-trace");
    let order = args.trace.order.unwrap_or_else(|| scene.default_order());
    let mut ctx = Run {
        run: TraceRun::new(start, open_ms, threads, order, &opts),
        spec: args.camera.spec(args.time, args.width, args.height),
        args,
        scene: &scene,
    };
    cli::with_threads(threads, || match mode {
        Mode::Render { image } if args.shade => ctx.render_shaded(&image),
        Mode::Render { image } => ctx.render(&image),
        Mode::Batch { rays, query, out } => ctx.batch(&rays, query, &out),
        Mode::Bench { set, shadow, wave } => ctx.bench(set, shadow, wave),
        Mode::Verify | Mode::Frames { .. } => Ok(()),
    })
}

/// `--verify`: every byte, checksum and invariant; each defect on stderr.
fn verify(args: &Args) -> Result<(), Error> {
    let v = Verification::run(&args.file)?;
    if args.json {
        cli::print_json(&v)?;
    } else if v.ok {
        cli::print_text(&format!("{v}\n"))?;
    }
    for d in &v.report.defects {
        eprintln!("oavm-trace: {}: {d}", args.file.display());
    }
    v.result()
}

/// `--frames A..B`: an animation, each frame updated into the file (or packed whole, with
/// --rebuild) and rendered (`oavm::render::animate`), on a pool sized before any frame's scene
/// is opened ([`Pool::BeforeOpen`]).
fn frames(args: &Args, out_dir: &Path, range: std::ops::Range<u64>) -> Result<(), Error> {
    let view = args
        .camera
        .view
        .as_deref()
        .ok_or_else(|| Error::Invalid("--frames needs --view SCENE.aff".into()))?;
    let anim = match &args.frame_meshes {
        Some(pattern) => Animation::with_meshes(view, pattern, range)?,
        None => Animation::new(view, range)?,
    };
    let opts = AnimateOptions {
        mode: match args.rebuild {
            true => animate::Mode::Rebuild,
            false => animate::Mode::Update,
        },
        out_dir: Some(out_dir.to_owned()),
        width: args.width,
        height: args.height,
        max_depth: args.depth.unwrap_or(render::DEFAULT_MAX_DEPTH),
        camera: match args.camera.camera_path {
            true => CameraChoice::Path,
            false => CameraChoice::View,
        },
        light: args.camera.light,
        scene: args.trace.scene_options(Pool::BeforeOpen),
        order: args.trace.order,
        ..AnimateOptions::default()
    };
    // Each line as it happens, unless the run reports in JSON at its end.
    let line = |what: &dyn std::fmt::Display| match args.json {
        true => Ok(()),
        false => cli::print_text(&format!("{what}\n")),
    };
    cli::with_threads(opts.scene.threads, || {
        let packed = match args.pack {
            true => Some(anim.pack_first(&args.file, &opts.pack)?),
            false => None,
        };
        packed.as_ref().map_or(Ok(()), |p| line(p))?;
        let mut printed = Ok(());
        let animation = animate::animate(&anim, &args.file, &opts, &mut |r| {
            if printed.is_ok() {
                printed = line(r);
            }
        })?;
        printed?;
        match args.json {
            true => cli::print_json(&AnimationRun { packed, animation }),
            false => line(&animation),
        }
    })
}

/// One tracing run: the arguments, the scene, the run's figures besides its rays, and the
/// camera, light and image size the arguments ask for.
struct Run<'a> {
    args: &'a Args,
    scene: &'a Scene,
    run: TraceRun,
    spec: ShotSpec,
}

impl Run<'_> {
    /// The pager's figures of `page`, as the clause that ends a line of text.
    fn pager(&self, page: &PageReport) -> String {
        page.clause(self.scene.peak_resident_bytes(), self.scene.budget())
    }

    /// Prints a render's report: as JSON in the run's envelope, or as its line of text, the
    /// rate of its rays (`total`) and the pager's figures.
    fn rendered<T: Serialize + Display>(
        &self,
        report: &T,
        total: &RenderTotal,
    ) -> Result<(), Error> {
        if self.args.json {
            return cli::print_json(&self.run.report(self.scene, report));
        }
        let rate = self.run.rate(total.mrays_per_s);
        cli::print_text(&format!("{report}, {rate}{}\n", self.pager(&total.page)))
    }

    /// Render mode: the image, written only once every pixel is traced.
    fn render(&mut self, image: &Path) -> Result<(), Error> {
        let out = Output::create(image, &[&self.args.file])?;
        let opts = Shot::new(&self.spec, &self.scene.bounds())?.render_options(self.run.order);
        self.run.first_ray();
        let (img, stats) = render::render(self.scene, &opts)?;
        render::write_png(out, &img)?;
        let report = RenderReport::new(image, stats);
        self.rendered(&report, &report.total)
    }

    /// Render mode with --shade: the scene's materials and lights (the --view scene's, posed
    /// at --time, which must be the scene the file was packed from), Whitted-style.
    fn render_shaded(&mut self, image: &Path) -> Result<(), Error> {
        let out = Output::create(image, &[&self.args.file])?;
        let shot = ShadedShot::new(self.scene, &self.spec, self.args.depth, self.run.order)?;
        self.run.first_ray();
        let (img, stats) = shot.render(self.scene)?;
        render::write_png(out, &img)?;
        let report = ShadedReport::new(image, &shot, stats);
        self.rendered(&report, &report.total)
    }

    /// Batch mode: traces a RAYS file and writes the answers to `out` (only once every ray
    /// is answered; the output's place is checked before the trace).
    fn batch(&mut self, rays_path: &Path, query: Query, out: &Path) -> Result<(), Error> {
        let output = Output::create(out, &[&self.args.file, rays_path])?;
        let rays = rays::read_rays(rays_path, oavm::logical::max_rays_in_memory())?;
        self.run.first_ray();
        let (answers, set) = self.scene.answer(&rays, query, self.run.order)?;
        answers.write(output)?;
        if self.args.json {
            return cli::print_json(&self.run.report(self.scene, &set));
        }
        cli::print_text(&format!(
            "{} rays, {}, {:.3} s, {}; per ray: {:.1} nodes, {:.1} volumes, {:.1} triangles{}; \
             wrote {}\n",
            set.rays,
            set.answered(),
            set.seconds,
            self.run.rate(set.mrays_per_s),
            set.nodes_visited_per_ray,
            set.volumes_crossed_per_ray,
            set.triangles_tested_per_ray,
            self.pager(&set.page),
            out.display()
        ))
    }

    /// Benchmark mode: traces --random or --primary rays (closest hit), then with --shadow a
    /// shadow ray from every hit (in waves, --wave); reports each set and the total, writes
    /// nothing.
    fn bench(&mut self, set: RaySet, shadow: bool, wave: usize) -> Result<(), Error> {
        let bounds = self.scene.bounds();
        let shot = Shot::new(&self.spec, &bounds)?;
        let rays = set.rays(&bounds, &shot.camera)?;
        self.run.first_ray();
        let light = shadow.then_some(shot.light);
        let order = self.run.order;
        let frame = (self.scene).trace_frame(&rays, &FrameOptions { light, wave, order })?;
        let figures = frame.figures(set.name(), shadow);
        if self.args.json {
            return cli::print_json(&self.run.report(self.scene, &figures));
        }
        let mut text = String::new();
        for s in &figures.sets {
            text += &format!("{s}{}\n", self.pager(&s.report.page));
        }
        let r = &self.run;
        text += &format!(
            "{} threads, order {}, open {:.3} ms, first ray {:.3} ms after start\n",
            r.threads, r.order, r.open_ms, r.first_ray_ms
        );
        cli::print_text(&text)
    }
}
