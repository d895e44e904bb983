//! `oavm-trace FILE.oavm`: traces rays through a packed file, memory-mapped, with no rebuild.
//! Renders an image by default; traces ray files in batch mode, or rays it makes itself in
//! benchmark mode; verifies files. Every trace runs within `--mem-budget` and reports what the
//! pager read and what the process used (peak RSS, bytes read from the disk).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::Parser;
use oavm::cli::{main_with, parse_bytes, with_threads};
use oavm::logical::{Order, SceneOptions};
use oavm::rays::{self, Bounds, Camera};
use oavm::render::{self, RenderOptions};
use oavm::{Counters, Error, Hit, Ray, Scene};
use serde_json::{Value, json};

/// Traces rays through an .oavm file made by oavm-pack.
///
/// With no mode option, renders the model from a camera that frames it (or from the viewpoint of
/// a BART scene, --view), shaded by a point light with shadows, and writes a PNG. With --rays and
/// --hits (closest hit) or --occluded (any hit), traces a ray file in the formats of RAYS.md.
/// With --random N or --primary WxH (and --shadow), traces rays it makes and reports the figures
/// only. With --verify, checks every byte of the file.
#[derive(Parser, Debug)]
#[command(name = "oavm-trace", version)]
struct Args {
    /// The .oavm file.
    file: PathBuf,
    /// Batch mode: a RAYS file to trace.
    #[arg(long, value_name = "RAYS")]
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
    /// ray sets of `cargo run --example rays`), closest hit; nothing is written.
    #[arg(long, value_name = "N", conflicts_with_all = ["rays", "primary"])]
    random: Option<usize>,
    /// Benchmark mode: trace the WxH primary rays of the camera (as for rendering: --eye,
    /// --target, --fov, --view...), closest hit; nothing is written.
    #[arg(long, value_name = "WxH", value_parser = parse_size, conflicts_with = "rays")]
    primary: Option<(u32, u32)>,
    /// Benchmark mode: then trace a shadow ray (any hit) from every hit to the light.
    #[arg(long)]
    shadow: bool,
    /// Benchmark mode with --shadow: trace in waves of N rays, taken in the tracing order
    /// (--order), each wave's shadow rays right after its primary ones, while the blocks they
    /// start in are still in memory, as a renderer would (0: all primary rays, then all shadow
    /// rays). The answers are the same.
    #[arg(long, value_name = "N", default_value_t = 65536)]
    wave: usize,
    /// Seed of --random.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Bytes of decoded blocks kept in memory (e.g. 512M, 1.5G; default: no limit). Raised to
    /// what one block per thread needs for compressed files (see the report's pager budget).
    #[arg(long, value_name = "SIZE", value_parser = parse_bytes)]
    mem_budget: Option<u64>,
    /// Do not check a raw block's checksum when it is paged in: only the pages a walk touches
    /// are read (far less from the disk when rays pass through blocks), but a damaged block is
    /// no longer caught by its checksum (reads stay bounds-checked: wrong answers, never a
    /// crash). `--verify` checks everything regardless.
    #[arg(long)]
    no_block_checks: bool,
    /// Order of tracing: morton (rays that enter the model near each other, in the same
    /// direction octant, together; image tiles in Morton order), blocks (rays binned by the
    /// first block they need, found in the top tree, then as morton) or none (as given; image
    /// rows). The answers are the same; the blocks read again under a small --mem-budget are
    /// not. Default: blocks with --mem-budget, morton without.
    #[arg(long, value_parser = parse_order)]
    order: Option<Order>,
    /// Check every section, checksum and invariant; exit non-zero on any defect.
    #[arg(long, conflicts_with_all = ["rays", "hits", "occluded", "random", "primary"])]
    verify: bool,
    /// Image to write (default: the file's name with .png).
    #[arg(short, long, value_name = "PNG")]
    output: Option<PathBuf>,
    /// Image width (default 1024, or the --view scene's resolution).
    #[arg(long)]
    width: Option<u32>,
    /// Image height (default 768, or the --view scene's resolution).
    #[arg(long)]
    height: Option<u32>,
    /// Take the camera from this BART AFF scene's viewpoint (`v`: from, at, up, and angle as the
    /// vertical field of view) and the light from its first light (`l`), or the viewpoint
    /// without one; the image size is the scene's resolution unless --width/--height are given.
    #[arg(long, value_name = "SCENE.aff", conflicts_with_all = ["eye", "target", "fov", "up"])]
    view: Option<PathBuf>,
    /// With --view: take the camera from the scene's animated camera path (`k camera`) at its
    /// first frame instead of its `v` block (BART's own animation frame).
    #[arg(long, requires = "view")]
    camera_path: bool,
    /// Camera position (default: in front of the model, framing it).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3)]
    eye: Option<[f64; 3]>,
    /// Point the camera looks at (default: the model's centre).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3)]
    target: Option<[f64; 3]>,
    /// Camera up vector.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, default_value = "0,1,0")]
    up: [f64; 3],
    /// Vertical field of view in degrees.
    #[arg(long, default_value_t = 40.0)]
    fov: f64,
    /// Point light position (default: above, right and in front of the model).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3)]
    light: Option<[f64; 3]>,
    /// Worker threads (0: one per core; with --mem-budget, eight per core, so that some
    /// threads trace while others wait for blocks from the disk).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Print one JSON object with the figures of the run.
    #[arg(long)]
    json: bool,
}

impl Args {
    /// `--order`, or its default: binned by block under a budget (on the 130M-triangle file in
    /// a 1.5 GiB cgroup, zstd, 10^6 random rays: 0.38 of the unlimited speed sorted by Morton
    /// key, 0.80 binned; README, out of core), Morton otherwise (no top-tree walk per ray).
    fn order(&self) -> Order {
        self.order.unwrap_or(if self.mem_budget.is_some() {
            Order::Blocks
        } else {
            Order::Morton
        })
    }
}

fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("{p:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err(format!("expected three finite numbers X,Y,Z, got {s:?}")),
    }
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got {s:?}"))?;
    let dim = |v: &str| match v.trim().parse::<u32>() {
        Ok(n) if (1..=16384).contains(&n) => Ok(n),
        _ => Err(format!("{s:?}: sizes are 1 to 16384 pixels")),
    };
    Ok((dim(w)?, dim(h)?))
}

fn parse_order(s: &str) -> Result<Order, String> {
    s.parse()
}

fn main() -> ExitCode {
    let start = Instant::now();
    let args = Args::parse();
    main_with("oavm-trace", || {
        with_threads(thread_count(&args), || run(&args, start))
    })
}

/// Threads waiting on the disk per core when a budget makes the tracer read blocks again: on
/// the 130M-triangle file in a 1.5 GiB cgroup, 16 threads on 2 cores traced 1.7 to 2.2 times
/// as fast as 2 (README, out of core), and no slower without a limit.
const IO_THREADS_PER_CORE: usize = 8;

/// `--threads`, or its default (0 lets rayon take one per core).
fn thread_count(args: &Args) -> usize {
    match (args.threads, args.mem_budget) {
        (0, Some(_)) => {
            std::thread::available_parallelism().map_or(1, |n| n.get()) * IO_THREADS_PER_CORE
        }
        (n, _) => n,
    }
}

fn run(args: &Args, start: Instant) -> Result<(), Error> {
    if args.rays.is_some() && args.hits.is_none() && args.occluded.is_none() {
        return Err(Error::Invalid(
            "--rays needs --hits (closest hit) or --occluded (any hit)".into(),
        ));
    }
    if args.shadow && args.random.is_none() && args.primary.is_none() {
        return Err(Error::Invalid(
            "--shadow needs --random N or --primary WxH".into(),
        ));
    }
    let t = Instant::now();
    let scene = Scene::open_with(
        &args.file,
        &SceneOptions {
            mem_budget: args.mem_budget.unwrap_or(u64::MAX),
            threads: 0,
            check_blocks: !args.no_block_checks,
        },
    )?;
    let open_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut report = Report {
        args,
        start,
        open_ms,
        threads: rayon::current_num_threads(),
        start_to_first_ray_ms: 0.0,
        io_before: None,
    };

    if args.verify {
        let t = Instant::now();
        let report = scene.verify();
        let seconds = t.elapsed().as_secs_f64();
        if args.json {
            print(
                &json!({ "file": args.file, "ok": report.is_ok(), "seconds": seconds, "report": report }),
            )?;
        } else if report.is_ok() {
            print_text(&format!(
                "{}: ok ({} bytes, {} sections, every checksum and invariant holds; {:.3} s)\n",
                args.file.display(),
                report.bytes_checked,
                report.sections_checked,
                seconds
            ))?;
        }
        if !report.is_ok() {
            for d in &report.defects {
                eprintln!("oavm-trace: {}: {d}", args.file.display());
            }
            return Err(Error::Invalid(format!(
                "{}: verification failed ({} defects)",
                args.file.display(),
                report.defects.len()
            )));
        }
        return Ok(());
    }

    if let Some(rays_path) = &args.rays {
        return batch(&scene, rays_path, &mut report);
    }

    let h = scene.file().header();
    let bounds = Bounds {
        min: h.mesh_min,
        max: h.mesh_max,
    };
    let (camera, light, (width, height)) = camera(args, &bounds)?;
    if args.random.is_some() || args.primary.is_some() {
        return bench(&scene, &bounds, &camera, light, &mut report);
    }

    // Default: render.
    let opts = RenderOptions {
        width: args.width.unwrap_or(width),
        height: args.height.unwrap_or(height),
        camera,
        light,
        order: args.order(),
    };
    report.first_ray();
    let (image, stats) = render::render(&scene, &opts)?;
    let out = args
        .output
        .clone()
        .unwrap_or_else(|| default_png(&args.file));
    render::write_png(&out, &image)?;
    let rays = stats.primary.rays + stats.shadow.rays;
    let mrays = rays as f64 / stats.seconds.max(1e-12) / 1e6;
    let all = stats.primary + stats.shadow;
    if args.json {
        let mut v = report.common(&scene);
        v["image"] = json!(out);
        v["rays"] = json!(rays);
        v["seconds"] = json!(stats.seconds);
        v["mrays_per_s"] = json!(mrays);
        v["page"] = page_json(&all);
        v["render"] = json!(stats);
        print(&v)?;
    } else {
        print_text(&format!(
            "wrote {} ({}x{}): {} primary rays ({} hit), {} shadow rays ({} shadowed), {:.3} s, \
             {mrays:.2} Mrays/s on {} threads (open {:.3} ms){}\n",
            out.display(),
            stats.width,
            stats.height,
            stats.primary.rays,
            stats.hits,
            stats.shadow.rays,
            stats.shadowed,
            stats.seconds,
            report.threads,
            report.open_ms,
            report.paging_text(&scene, &all),
        ))?;
    }
    Ok(())
}

/// A camera, its light and its image size.
type Shot = (Camera, [f32; 3], (u32, u32));

/// The camera, light and image size of the render and of --primary: from --view, or framing
/// the model and adjusted by --eye, --target, --up, --fov; the light from --light, else the
/// scene's, else the default.
fn camera(args: &Args, bounds: &Bounds) -> Result<Shot, Error> {
    let (camera, scene_light, size) = if let Some(view_path) = &args.view {
        let aff = oavm::mesh::load_aff(view_path, None)?;
        let v = if args.camera_path {
            aff.camera_path.ok_or_else(|| {
                Error::Invalid(format!(
                    "{}: the scene has no camera path (`k camera` and a `v` block) for --camera-path",
                    view_path.display()
                ))
            })?
        } else {
            aff.view.ok_or_else(|| {
                Error::Invalid(format!(
                    "{}: the scene has no viewpoint (`v` block) for --view",
                    view_path.display()
                ))
            })?
        };
        let camera = Camera::look_at(v.from, v.at, v.up, v.angle_deg)
            .map_err(|e| Error::Invalid(format!("{}: viewpoint: {e}", view_path.display())))?;
        let light = aff.lights.first().copied().unwrap_or(v.from);
        (camera, Some(light), v.resolution)
    } else {
        let mut camera = Camera::framing(bounds);
        if let Some(target) = args.target {
            camera.target = target;
        }
        if let Some(eye) = args.eye {
            camera.eye = eye;
        }
        camera.up = args.up;
        camera.fov_y = args.fov;
        if !(camera.fov_y > 0.0 && camera.fov_y < 180.0) || camera.eye == camera.target {
            return Err(Error::Invalid(
                "the camera needs 0 < --fov < 180 and --eye apart from --target".into(),
            ));
        }
        (camera, None, (1024, 768))
    };
    let light = args
        .light
        .or(scene_light)
        .map(|l| l.map(|c| c as f32))
        .unwrap_or_else(|| rays::default_light(bounds));
    Ok((camera, light, size))
}

/// Batch mode: traces a RAYS file and writes the answers (only once every ray is answered).
fn batch(scene: &Scene, rays_path: &Path, report: &mut Report) -> Result<(), Error> {
    let args = report.args;
    let rays = rays::read_rays(rays_path)?;
    report.first_ray();
    let t = Instant::now();
    let (c, seconds, answers, label, out_path) = if let Some(hits_path) = &args.hits {
        let mut hits = vec![Hit::MISS; rays.len()];
        let c = scene.intersect_batch_ordered(&rays, &mut hits, args.order())?;
        let seconds = t.elapsed().as_secs_f64();
        rays::write_hits(hits_path, &hits)?;
        let n = hits.iter().filter(|h| h.is_hit()).count();
        (c, seconds, n, "hits", hits_path)
    } else {
        let occl_path = args
            .occluded
            .as_ref()
            .ok_or_else(|| Error::Invalid("no output".into()))?;
        let mut occ = vec![0u8; rays.len()];
        let c = scene.occluded_batch_ordered(&rays, &mut occ, args.order())?;
        let seconds = t.elapsed().as_secs_f64();
        rays::write_occlusion(occl_path, &occ)?;
        let n = occ.iter().filter(|&&o| o == 1).count();
        (c, seconds, n, "occluded", occl_path)
    };
    let per_ray = |x: u64| x as f64 / (c.rays.max(1)) as f64;
    let mrays = rays.len() as f64 / seconds.max(1e-12) / 1e6;
    if args.json {
        let mut v = report.common(scene);
        merge(&mut v, set_json(label, answers, &c, seconds));
        print(&v)?;
    } else {
        print_text(&format!(
            "{} rays, {answers} {label}, {seconds:.3} s, {mrays:.2} Mrays/s on {} threads \
             (open {:.3} ms); per ray: {:.1} nodes, {:.1} volumes, {:.1} triangles{}; wrote {}\n",
            rays.len(),
            report.threads,
            report.open_ms,
            per_ray(c.nodes_visited),
            per_ray(c.volumes_crossed),
            per_ray(c.triangles_tested),
            report.paging_text(scene, &c),
            out_path.display()
        ))?;
    }
    Ok(())
}

/// The shadow rays (`rays::shadow_ray`) of those of `rays` that `hits` says hit, with the index
/// (from `index`, one per ray) of the ray each comes from.
fn shadow_set(
    rays: &[Ray],
    hits: &[Hit],
    index: Vec<u32>,
    light: [f32; 3],
) -> (Vec<Ray>, Vec<u32>) {
    rays.iter()
        .zip(hits)
        .zip(index)
        .filter(|((_, h), _)| h.is_hit())
        .map(|((r, h), i)| (rays::shadow_ray(r, h.t, light), i))
        .unzip()
}

/// Benchmark mode: traces --random or --primary rays (closest hit), then with --shadow a shadow
/// ray from every hit (in waves, --wave); reports each set and the total, writes nothing.
fn bench(
    scene: &Scene,
    bounds: &Bounds,
    camera: &Camera,
    light: [f32; 3],
    report: &mut Report,
) -> Result<(), Error> {
    let args = report.args;
    let (name, rays) = match (args.random, args.primary) {
        (Some(n), _) => ("random", rays::random_rays(bounds, n, args.seed)),
        (None, Some((w, h))) => ("primary", camera.primary_rays(w, h)),
        (None, None) => return Err(Error::Invalid("no ray set".into())),
    };
    report.first_ray();
    let mut hits = vec![Hit::MISS; rays.len()];
    // Per primary ray with a hit: its shadow ray's answer.
    let mut occ_of = vec![0u8; if args.shadow { rays.len() } else { 0 }];
    let (mut primary, mut shadow) = ((Counters::default(), 0.0), (Counters::default(), 0.0));
    let wave = match args.wave {
        0 => rays.len().max(1),
        n => n,
    };
    if !args.shadow || wave >= rays.len() {
        let t = Instant::now();
        primary.0 = scene.intersect_batch_ordered(&rays, &mut hits, args.order())?;
        primary.1 = t.elapsed().as_secs_f64();
        if args.shadow {
            let t = Instant::now();
            let (sr, owners) = shadow_set(&rays, &hits, (0..rays.len() as u32).collect(), light);
            let mut occ = vec![0u8; sr.len()];
            shadow.0 = scene.occluded_batch_ordered(&sr, &mut occ, args.order())?;
            shadow.1 = t.elapsed().as_secs_f64();
            for (&i, o) in owners.iter().zip(&occ) {
                occ_of[i as usize] = *o;
            }
        }
    } else {
        // Waves of consecutive rays in the tracing order: each a region of space (and of the
        // image), whose shadow rays start in the blocks its primary rays just read.
        let t = Instant::now();
        let perm: Vec<u32> = match args.order() {
            Order::Morton => scene.morton_order(&rays),
            Order::Blocks => scene.block_order(&rays)?,
            Order::None | Order::Given => (0..rays.len() as u32).collect(),
        };
        // A wave is a run of that order already: traced as given (not sorted again), unless
        // the order is none.
        let wave_order = match args.order() {
            Order::None => Order::None,
            _ => Order::Given,
        };
        primary.1 += t.elapsed().as_secs_f64();
        for idx in perm.chunks(wave) {
            let t = Instant::now();
            let wr: Vec<Ray> = idx.iter().map(|&i| rays[i as usize]).collect();
            let mut wh = vec![Hit::MISS; wr.len()];
            primary.0 += scene.intersect_batch_ordered(&wr, &mut wh, wave_order)?;
            for (&i, h) in idx.iter().zip(&wh) {
                hits[i as usize] = *h;
            }
            primary.1 += t.elapsed().as_secs_f64();
            let t = Instant::now();
            let (sr, owners) = shadow_set(&wr, &wh, idx.to_vec(), light);
            let mut occ = vec![0u8; sr.len()];
            shadow.0 += scene.occluded_batch_ordered(&sr, &mut occ, args.order())?;
            for (&i, o) in owners.iter().zip(&occ) {
                occ_of[i as usize] = *o;
            }
            shadow.1 += t.elapsed().as_secs_f64();
        }
    }
    let mut sets = Vec::new();
    let n = hits.iter().filter(|h| h.is_hit()).count();
    let digest = answers_digest(bytemuck::cast_slice(&hits));
    sets.push((name, "hits", n, primary.0, primary.1, digest));
    let (mut total, mut seconds) = primary;
    if args.shadow {
        // In the order of `rays::shadow_rays`: the primary rays' order, those with a hit.
        let occ: Vec<u8> = hits
            .iter()
            .zip(&occ_of)
            .filter(|(h, _)| h.is_hit())
            .map(|(_, &o)| o)
            .collect();
        let n = occ.iter().filter(|&&o| o == 1).count();
        sets.push((
            "shadow",
            "occluded",
            n,
            shadow.0,
            shadow.1,
            answers_digest(&occ),
        ));
        (total, seconds) = (total + shadow.0, seconds + shadow.1);
    }
    if args.json {
        let mut v = report.common(scene);
        merge(&mut v, set_json("", 0, &total, seconds));
        v["sets"] = sets
            .iter()
            .map(|&(set, label, n, c, s, digest)| {
                let mut v = json!({ "set": set, "answers_xxh3": format!("{digest:016x}") });
                merge(&mut v, set_json(label, n, &c, s));
                v
            })
            .collect();
        print(&v)?;
    } else {
        let mut text = String::new();
        for &(set, label, n, c, s, _) in &sets {
            text += &format!(
                "{set}: {} rays, {n} {label}, {s:.3} s, {:.2} Mrays/s{}\n",
                c.rays,
                c.rays as f64 / s.max(1e-12) / 1e6,
                report.paging_text(scene, &c)
            );
        }
        text += &format!(
            "{} threads, order {}, open {:.3} ms, first ray {:.3} ms after start\n",
            report.threads,
            args.order(),
            report.open_ms,
            report.start_to_first_ray_ms
        );
        print_text(&text)?;
    }
    Ok(())
}

/// What every tracing mode reports besides its rays: times, the pager, the process's memory
/// and disk reads.
struct Report<'a> {
    args: &'a Args,
    /// `main`'s entry (the time before it, exec and loading, is not counted).
    start: Instant,
    open_ms: f64,
    threads: usize,
    start_to_first_ray_ms: f64,
    /// The process's `read_bytes` just before the first ray.
    io_before: Option<u64>,
}

impl Report<'_> {
    /// Marks the moment the first ray is ready to be traced.
    fn first_ray(&mut self) {
        self.start_to_first_ray_ms = self.start.elapsed().as_secs_f64() * 1e3;
        self.io_before = proc_field("/proc/self/io", "read_bytes:");
    }

    fn common(&self, scene: &Scene) -> Value {
        let io_after = proc_field("/proc/self/io", "read_bytes:");
        let pager = scene.pager();
        json!({
            "file": self.args.file,
            "file_bytes": scene.file().bytes().len(),
            "threads": self.threads,
            "order": self.args.order(),
            "open_ms": self.open_ms,
            "start_to_first_ray_ms": self.start_to_first_ray_ms,
            "mem_budget": self.args.mem_budget,
            "block_checks": !self.args.no_block_checks,
            "pager_budget": pager.budget(),
            "pager_peak_resident_bytes": pager.peak_resident_bytes(),
            "pager_slots": pager.slot_count(),
            "blocks": scene.file().directory().len(),
            "max_block_raw_len": scene.file().header().max_block_raw_len,
            "peak_rss_bytes": proc_field("/proc/self/status", "VmHWM:").map(|kb| kb * 1024),
            "disk_read_bytes_before_trace": self.io_before,
            "disk_read_bytes_trace": io_after.zip(self.io_before).map(|(a, b)| a.saturating_sub(b)),
        })
    }

    /// The pager's figures for `c`, as a clause of the text report.
    fn paging_text(&self, scene: &Scene, c: &Counters) -> String {
        let p = &c.page;
        format!(
            "; pager: {} blocks asked, {} misses ({:.1} % hits), {:.1} MB read ({:.0} B/ray), \
             peak {:.1} MB resident{}",
            p.requested,
            p.misses,
            100.0 * hit_rate(c),
            p.bytes_read as f64 / 1e6,
            p.bytes_read as f64 / c.rays.max(1) as f64,
            scene.pager().peak_resident_bytes() as f64 / 1e6,
            match self.args.mem_budget {
                Some(_) => format!(" of {:.1} MB", scene.pager().budget() as f64 / 1e6),
                None => String::new(),
            }
        )
    }
}

fn hit_rate(c: &Counters) -> f64 {
    c.page.hits as f64 / c.page.requested.max(1) as f64
}

/// The pager's counters of `c`, with the hit rate and bytes read per ray.
fn page_json(c: &Counters) -> Value {
    let mut v = json!(c.page);
    v["hit_rate"] = json!(hit_rate(c));
    v["bytes_read_per_ray"] = json!(c.page.bytes_read as f64 / c.rays.max(1) as f64);
    v
}

/// The figures of one set of rays: `answered` is `label` (hits, occluded; none if empty).
/// xxh3-64 of a set's answers (closest hits as their HITS records, or the OCCL bytes): runs
/// that agree ray for ray have the same digest.
fn answers_digest(bytes: &[u8]) -> u64 {
    xxhash_rust::xxh3::xxh3_64(bytes)
}

fn set_json(label: &str, answered: usize, c: &Counters, seconds: f64) -> Value {
    let per_ray = |x: u64| x as f64 / (c.rays.max(1)) as f64;
    let mut v = json!({
        "rays": c.rays,
        "seconds": seconds,
        "mrays_per_s": c.rays as f64 / seconds.max(1e-12) / 1e6,
        "nodes_visited": c.nodes_visited,
        "leaves_visited": c.leaves_visited,
        "volumes_crossed": c.volumes_crossed,
        "leaves_culled": c.leaves_culled,
        "links_culled": c.links_culled,
        "triangles_tested": c.triangles_tested,
        "nodes_visited_per_ray": per_ray(c.nodes_visited),
        "leaves_visited_per_ray": per_ray(c.leaves_visited),
        "triangles_tested_per_ray": per_ray(c.triangles_tested),
        "page": page_json(c),
    });
    if !label.is_empty() {
        v[label] = json!(answered);
    }
    v
}

fn merge(into: &mut Value, from: Value) {
    if let (Value::Object(a), Value::Object(b)) = (into, from) {
        a.extend(b);
    }
}

/// The number after `key` in a `/proc` file of `key value` lines (`None` if unreadable: not
/// Linux, or a sandbox without it).
fn proc_field(path: &str, key: &str) -> Option<u64> {
    let text = std::fs::read_to_string(path).ok()?;
    let line = text.lines().find(|l| l.starts_with(key))?;
    line[key.len()..].split_whitespace().next()?.parse().ok()
}

fn default_png(file: &Path) -> PathBuf {
    file.with_extension("png")
}

fn print(v: &serde_json::Value) -> Result<(), Error> {
    print_text(&(serde_json::to_string_pretty(v).unwrap_or_default() + "\n"))
}

fn print_text(s: &str) -> Result<(), Error> {
    std::io::stdout()
        .lock()
        .write_all(s.as_bytes())
        .map_err(|e| Error::io("stdout", e))
}
