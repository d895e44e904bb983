//! `oavm-trace FILE.oavm`: traces rays through a packed file, memory-mapped, with no rebuild.
//! Renders an image by default; traces ray files in batch mode, or rays it makes itself in
//! benchmark mode; verifies files; renders the frames of an animation. Glue: the arguments
//! become a typed [`Mode`] (in `args.rs`), the library does the work (the shot of a render,
//! `oavm::render::Shot`; the benchmark's frame, `oavm::logical::FrameFigures`; the animation,
//! `oavm::render::animate`), this prints what it reports.

mod args;
#[path = "../cli/mod.rs"]
mod cli;

use std::fmt::Display;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

use args::{Args, Mode};
use clap::Parser;
use cli::Pool;
use oavm::logical::{FrameOptions, PageReport, Query, RaySet, TraceRun, Verification};
use oavm::output::Output;
use oavm::rays;
use oavm::render::animate::{self, AnimateOptions, Animation, AnimationRun, CameraChoice};
use oavm::render::{self, RenderReport, RenderTotal, ShadedReport, ShadedShot, Shot, ShotSpec};
use oavm::{Error, Scene};
use serde::Serialize;

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
    // (Reported as traced: a stream asked for under a budget that holds the file is not.)
    let order = scene.streamed(args.trace.order.unwrap_or_else(|| scene.default_order()));
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
