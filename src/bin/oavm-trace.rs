//! `oavm-trace FILE.oavm`: traces rays through a packed file, memory-mapped, with no rebuild.
//! Renders an image by default; traces ray files in batch mode; verifies files.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::Parser;
use oavm::cli::{main_with, with_threads};
use oavm::rays::{self, Bounds, Camera};
use oavm::render::{self, RenderOptions};
use oavm::{Error, Hit, Scene};
use serde_json::json;

/// Traces rays through an .oavm file made by oavm-pack.
///
/// With no mode option, renders the model from a camera that frames it (or from the viewpoint of
/// a BART scene, --view), shaded by a point light with shadows, and writes a PNG. With --rays and --hits (closest hit) or --occluded (any hit),
/// traces a ray file in the formats of RAYS.md. With --verify, checks every byte of the file.
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
    /// Check every section, checksum and invariant; exit non-zero on any defect.
    #[arg(long, conflicts_with_all = ["rays", "hits", "occluded"])]
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
    /// Worker threads (0: one per core).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Print one JSON object with the figures of the run.
    #[arg(long)]
    json: bool,
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

fn main() -> ExitCode {
    let start = Instant::now();
    let args = Args::parse();
    main_with("oavm-trace", || {
        with_threads(args.threads, || run(&args, start))
    })
}

fn run(args: &Args, start: Instant) -> Result<(), Error> {
    if args.rays.is_some() && args.hits.is_none() && args.occluded.is_none() {
        return Err(Error::Invalid(
            "--rays needs --hits (closest hit) or --occluded (any hit)".into(),
        ));
    }
    let t = Instant::now();
    let scene = Scene::open(&args.file)?;
    let open_ms = t.elapsed().as_secs_f64() * 1e3;
    let threads = rayon::current_num_threads();

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
        let rays = rays::read_rays(rays_path)?;
        let t = Instant::now();
        let start_to_first_ray_ms = start.elapsed().as_secs_f64() * 1e3;
        let (counters, answers, label, out_path) = if let Some(hits_path) = &args.hits {
            let mut hits = vec![Hit::MISS; rays.len()];
            let c = scene.intersect_batch(&rays, &mut hits)?;
            let seconds = t.elapsed().as_secs_f64();
            rays::write_hits(hits_path, &hits)?;
            let n = hits.iter().filter(|h| h.is_hit()).count();
            ((c, seconds), n, "hits", hits_path)
        } else {
            let occl_path = args
                .occluded
                .as_ref()
                .ok_or_else(|| Error::Invalid("no output".into()))?;
            let mut occ = vec![0u8; rays.len()];
            let c = scene.occluded_batch(&rays, &mut occ)?;
            let seconds = t.elapsed().as_secs_f64();
            rays::write_occlusion(occl_path, &occ)?;
            let n = occ.iter().filter(|&&o| o == 1).count();
            ((c, seconds), n, "occluded", occl_path)
        };
        let (c, seconds) = counters;
        let per_ray = |x: u64| x as f64 / (c.rays.max(1)) as f64;
        let mrays = rays.len() as f64 / seconds.max(1e-12) / 1e6;
        if args.json {
            let mut v = json!({
                "file": args.file,
                "rays": rays.len(),
                "seconds": seconds,
                "mrays_per_s": mrays,
                "threads": threads,
                "open_ms": open_ms,
                "start_to_first_ray_ms": start_to_first_ray_ms,
                "nodes_visited": c.nodes_visited,
                "leaves_visited": c.leaves_visited,
                "volumes_crossed": c.volumes_crossed,
                "triangles_tested": c.triangles_tested,
                "nodes_visited_per_ray": per_ray(c.nodes_visited),
                "triangles_tested_per_ray": per_ray(c.triangles_tested),
            });
            v[label] = json!(answers);
            print(&v)?;
        } else {
            print_text(&format!(
                "{} rays, {answers} {label}, {seconds:.3} s, {mrays:.2} Mrays/s on {threads} threads \
                 (open {open_ms:.3} ms); per ray: {:.1} nodes, {:.1} volumes, {:.1} triangles; wrote {}\n",
                rays.len(),
                per_ray(c.nodes_visited),
                per_ray(c.volumes_crossed),
                per_ray(c.triangles_tested),
                out_path.display()
            ))?;
        }
        return Ok(());
    }

    // Default: render.
    let h = scene.file().header();
    let bounds = Bounds {
        min: h.mesh_min,
        max: h.mesh_max,
    };
    let (camera, scene_light, (width, height)) = if let Some(view_path) = &args.view {
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
        let mut camera = Camera::framing(&bounds);
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
        .unwrap_or_else(|| rays::default_light(&bounds));
    let opts = RenderOptions {
        width: args.width.unwrap_or(width),
        height: args.height.unwrap_or(height),
        camera,
        light,
    };
    let (image, stats) = render::render(&scene, &opts)?;
    let out = args
        .output
        .clone()
        .unwrap_or_else(|| default_png(&args.file));
    render::write_png(&out, &image)?;
    let rays = stats.primary.rays + stats.shadow.rays;
    if args.json {
        print(&json!({
            "file": args.file,
            "image": out,
            "threads": threads,
            "open_ms": open_ms,
            "mrays_per_s": rays as f64 / stats.seconds / 1e6,
            "render": stats,
        }))?;
    } else {
        print_text(&format!(
            "wrote {} ({}x{}): {} primary rays ({} hit), {} shadow rays ({} shadowed), {:.3} s, \
             {:.2} Mrays/s on {threads} threads (open {open_ms:.3} ms)\n",
            out.display(),
            stats.width,
            stats.height,
            stats.primary.rays,
            stats.hits,
            stats.shadow.rays,
            stats.shadowed,
            stats.seconds,
            rays as f64 / stats.seconds / 1e6
        ))?;
    }
    Ok(())
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
