//! Animations (`oavm::render::animate`, `oavm-trace --frames`): frames brought into the file by
//! local updates render the same images, byte for byte, as the same frames packed whole; the
//! updates are local (a few blocks rebuilt of many); what moved shows in the images; Rain frames
//! read from mesh files animate the same way; bad ranges, missing frames and a file that cannot
//! be updated give errors naming the cause.
//!
//! The kitchen comes from `../shared/scenes` (a missing file fails). Rain is generated here
//! with the generator's own code (`tools/rain.rs`, compiled as a module, as `tests/integration/rain.rs`
//! does).

#[allow(dead_code)]
use crate::rain_example as rain;

use std::path::{Path, PathBuf};

use crate::common::{bin, run, shared_scene};
use clap::Parser;
use oavm::pack::{PackOptions, Quiet};
use oavm::rays::Camera;
use oavm::render::animate::{
    AnimateOptions, Animation, AnimationReport, CameraChoice, Mode, animate, frame_image_name,
    parse_frames,
};
use oavm::render::{Look, ShadedOptions, render_shaded};
use oavm::{Error, Scene};
use tempfile::TempDir;

/// Small images, so that the test runs in seconds.
const W: u32 = 64;
const H: u32 = 48;

fn opts(mode: Mode, out_dir: &Path, camera: CameraChoice) -> AnimateOptions {
    AnimateOptions {
        mode,
        out_dir: Some(out_dir.to_owned()),
        width: Some(W),
        height: Some(H),
        camera,
        ..AnimateOptions::default()
    }
}

fn run_animation(anim: &Animation, file: &Path, o: &AnimateOptions) -> AnimationReport {
    let mut seen = Vec::new();
    let r = animate(anim, file, o, &mut |f| seen.push(f.frame))
        .unwrap_or_else(|e| panic!("{:?} {}: {e}", o.mode, file.display()));
    assert_eq!(
        seen,
        anim.frames().collect::<Vec<_>>(),
        "told of every frame"
    );
    assert_eq!(r.frames, anim.frames().count() as u64);
    assert_eq!(r.per_frame.len() as u64, r.frames);
    assert_eq!((r.width, r.height), (W, H));
    assert!(r.fps > 0.0 && r.rays > 0, "{r:?}");
    r
}

/// The image files of both runs are the same, byte for byte, and so are the digests.
fn same_images(a: &AnimationReport, b: &AnimationReport, dir_a: &Path, dir_b: &Path) {
    for (fa, fb) in a.per_frame.iter().zip(&b.per_frame) {
        assert_eq!(fa.frame, fb.frame);
        let name = frame_image_name(fa.frame);
        assert_eq!(fa.image.as_deref(), Some(dir_a.join(&name).as_path()));
        let pa = std::fs::read(dir_a.join(&name)).unwrap();
        let pb = std::fs::read(dir_b.join(&name)).unwrap();
        assert!(
            pa == pb,
            "frame {}: the updated file's image differs from the rebuilt one's",
            fa.frame
        );
        assert_eq!(fa.image_xxh3, fb.image_xxh3, "frame {}", fa.frame);
        // The same triangles: the same rays of every kind.
        assert_eq!(fa.render.rays, fb.render.rays, "frame {}", fa.frame);
        assert_eq!(fa.render.hits, fb.render.hits, "frame {}", fa.frame);
        assert_eq!(fa.render.shadowed, fb.render.shadowed, "frame {}", fa.frame);
    }
}

/// Each frame's image differs from the previous one's.
fn frames_differ(r: &AnimationReport) {
    for w in r.per_frame.windows(2) {
        assert_ne!(
            w[0].image_xxh3, w[1].image_xxh3,
            "frames {} and {} rendered alike: nothing moved",
            w[0].frame, w[1].frame
        );
    }
}

/// The kitchen through frames 401..404 (the toy car drives around the table; BART's camera
/// path follows it), updated frame by frame from a file packed at frame 400, against the same
/// frames packed whole: the same images, byte for byte; every update local; and the car's
/// motion in the images (frame f's camera over the file as packed at frame 400 sees another
/// picture than over frame f's triangles).
#[test]
fn kitchen_updates_render_as_rebuilds() {
    let kitchen = shared_scene("bart/kitchen/kitchen.aff");
    let dir = TempDir::new().unwrap();
    let updated = dir.path().join("updated.oavm");
    let rebuilt = dir.path().join("rebuilt.oavm");
    let stale = dir.path().join("stale.oavm");

    // The file, packed at frame 400 with a root cube that holds frames 400..404.
    let all = Animation::new(&kitchen, 400..404).unwrap();
    let first = all.pack_first(&updated, &PackOptions::default()).unwrap();
    assert_eq!(first.frame, 400);
    std::fs::copy(&updated, &stale).unwrap();
    let before = Scene::open(&updated).unwrap().file().header().block_count;
    assert!(
        before > 8,
        "the kitchen is packed in {before} blocks: too few to be local"
    );

    let anim = Animation::new(&kitchen, 401..404).unwrap();
    let (dir_u, dir_r) = (dir.path().join("u"), dir.path().join("r"));
    let by_update = run_animation(
        &anim,
        &updated,
        &opts(Mode::Update, &dir_u, CameraChoice::Auto),
    );
    let mut o = opts(Mode::Rebuild, &dir_r, CameraChoice::Auto);
    o.pack.bounds = Some(first.bounds);
    let by_rebuild = run_animation(&anim, &rebuilt, &o);

    same_images(&by_update, &by_rebuild, &dir_u, &dir_r);
    frames_differ(&by_update);
    for (i, f) in by_update.per_frame.iter().enumerate() {
        let u = f.update.as_ref().expect("every frame moves the car");
        assert!(f.changed > 0 && u.moved > 0, "frame {}: {u:?}", f.frame);
        assert_eq!(u.generation, i as u64 + 2, "one generation a frame");
        assert!(
            u.blocks_rebuilt > 0 && u.blocks_rebuilt < u.blocks_before,
            "frame {}: {} of {} blocks rebuilt",
            f.frame,
            u.blocks_rebuilt,
            u.blocks_before
        );
        assert!(
            u.blocks_rebuilt * 4 < u.blocks_before,
            "frame {}: not local",
            f.frame
        );
        assert_eq!(f.bytes_written, u.bytes_written);
        assert!(f.pack.is_none());
        assert!(f.update_seconds >= u.build_seconds + u.write_seconds);
    }
    for f in &by_rebuild.per_frame {
        let p = f.pack.as_ref().expect("a pack every frame");
        assert!(f.update.is_none());
        assert_eq!(f.bytes_written, p.file_bytes);
        assert_eq!(f.file_bytes, p.file_bytes);
    }
    assert_eq!(by_rebuild.bounds, Some(first.bounds));
    // An update appends: the file grows by what each frame writes.
    let last = by_update.per_frame.last().unwrap();
    assert!(last.file_bytes >= first.pack.file_bytes + by_update.bytes_written - 4096 * 3);

    // The car moved: frame f's camera and look over the triangles of frame 400 give another
    // image than the updated file gave.
    let old = Scene::open(&stale).unwrap();
    for f in &by_update.per_frame {
        let frame = anim.frame(f.frame).unwrap();
        let v = frame
            .view
            .camera_path
            .expect("the kitchen has a camera path");
        let camera = Camera::look_at(v.from, v.at, v.up, v.angle_deg).unwrap();
        let (img, _) = render_shaded(
            &old,
            &ShadedOptions::new(W, H, camera),
            &Look::from_aff(&frame.view),
        )
        .unwrap();
        assert_ne!(
            format!("{:016x}", xxhash_rust::xxh3::xxh3_64(&img.rgb)),
            f.image_xxh3,
            "frame {}: the car's motion does not show",
            f.frame
        );
    }
}

/// Writes Rain frames `frames` of `balls` balls into `dir`; returns the view and the pattern.
fn rain_frames(dir: &Path, balls: u64, frames: &str) -> (PathBuf, String) {
    let args = rain::Args::try_parse_from([
        "rain",
        "--balls",
        &balls.to_string(),
        "--seed",
        "1",
        "--frames",
        frames,
        "--out",
        dir.to_str().unwrap(),
    ])
    .unwrap();
    let c = rain::Config::new(&args).unwrap();
    let report = rain::write_all(&c, |_| {}).unwrap();
    (report.view, dir.join("rain_{}.ply").display().to_string())
}

/// Rain's frames read from PLY files, seen through its view file: updated from a file packed
/// at frame 0 (whose root cube holds the three frames), the same images as rebuilt, byte for
/// byte, every ball moved and each frame different.
#[test]
fn rain_frames_animate_as_rebuilds() {
    let dir = TempDir::new().unwrap();
    let (view, pattern) = rain_frames(&dir.path().join("rain"), 2000, "0..3");
    let anim = Animation::with_meshes(&view, &pattern, 0..3).unwrap();
    let file = dir.path().join("rain.oavm");
    let first = anim.pack_first(&file, &PackOptions::default()).unwrap();
    // Every frame spans the documented box (its ground and the marker at its top corner).
    let (lo, hi) = first.bounds;
    for k in 0..3 {
        assert_eq!(lo[k] as f64, rain::BOX_MIN[k]);
        assert_eq!(hi[k] as f64, rain::BOX_MAX[k]);
    }
    let (dir_u, dir_r) = (dir.path().join("u"), dir.path().join("r"));
    let by_update = run_animation(
        &anim,
        &file,
        &opts(Mode::Update, &dir_u, CameraChoice::View),
    );
    let by_rebuild = run_animation(
        &anim,
        &dir.path().join("rebuilt.oavm"),
        &opts(Mode::Rebuild, &dir_r, CameraChoice::View),
    );
    same_images(&by_update, &by_rebuild, &dir_u, &dir_r);
    frames_differ(&by_update);
    let triangles = 2 + 2000 * 8 + 1;
    // Frame 0 is what was packed: nothing to write.
    let f0 = &by_update.per_frame[0];
    assert_eq!((f0.changed, f0.bytes_written), (0, 0));
    assert!(f0.update.is_none());
    for f in &by_update.per_frame[1..] {
        let u = f.update.as_ref().unwrap();
        assert_eq!(f.triangles, triangles);
        assert_eq!(u.moved, 2000 * 8, "frame {}: every ball falls", f.frame);
        assert!(u.blocks_rebuilt > 0 && u.blocks_rebuilt <= u.blocks_before);
    }
    // With a file made by `pack_first` of the same range, the rebuild uses its root cube.
    assert_eq!(by_rebuild.bounds, Some(first.bounds));
    for f in &by_rebuild.per_frame {
        assert!(f.pack.as_ref().unwrap().streaming.is_none());
    }

    // Frames too large for memory are packed streaming from their files (as `oavm-pack`
    // decides; here a memory budget asks for it): the same images, and the first pack and
    // every rebuild streamed, without reading the frame into memory first.
    let budget = PackOptions {
        mem_budget: Some(16 << 20),
        ..PackOptions::default()
    };
    let streamed_file = dir.path().join("streamed.oavm");
    let first_streamed = anim.pack_first(&streamed_file, &budget).unwrap();
    assert!(first_streamed.pack.streaming.is_some());
    assert_eq!(first_streamed.pack.stats.input_triangles, triangles);
    let dir_s = dir.path().join("s");
    let mut streamed_opts = opts(Mode::Rebuild, &dir_s, CameraChoice::View);
    streamed_opts.pack = PackOptions {
        bounds: Some(first.bounds),
        ..budget
    };
    let by_streaming = run_animation(
        &anim,
        &dir.path().join("streamed_rebuilt.oavm"),
        &streamed_opts,
    );
    same_images(&by_update, &by_streaming, &dir_u, &dir_s);
    for f in &by_streaming.per_frame {
        assert!(
            f.pack.as_ref().unwrap().streaming.is_some(),
            "frame {}",
            f.frame
        );
        assert_eq!(f.triangles, triangles);
    }
}

fn err_text(r: Result<impl std::fmt::Debug, Error>) -> String {
    match r {
        Ok(v) => panic!("expected an error, got {v:?}"),
        Err(e) => e.to_string(),
    }
}

#[track_caller]
fn says(text: &str, parts: &[&str]) {
    for p in parts {
        assert!(text.contains(p), "{text:?} does not say {p:?}");
    }
}

/// Bad ranges, missing frames, a pattern without a place for the frame number, a scene
/// without an animation and a file that cannot be updated: errors that name the cause, before
/// anything is written.
#[test]
fn bad_ranges_and_files_are_refused() {
    let kitchen = shared_scene("bart/kitchen/kitchen.aff");
    let dir = TempDir::new().unwrap();
    let (view, pattern) = rain_frames(&dir.path().join("rain"), 50, "0..2");

    says(
        &err_text(Animation::new(&kitchen, 5..5)),
        &["frames 5..5", "empty"],
    );
    says(
        &err_text(Animation::new(&kitchen, 798..801)),
        &["frames 798..801", "kitchen.aff", "800 frames", "frame 800"],
    );
    says(
        &err_text(Animation::new(&view, 0..2)),
        &["rain.aff", "no animation", "mesh per frame"],
    );
    says(
        &err_text(Animation::with_meshes(&view, &pattern, 0..4)),
        &["frame 2", "rain_00002.ply", "missing"],
    );
    says(
        &err_text(Animation::with_meshes(&view, "frames.ply", 0..1)),
        &["frames.ply", "no {}"],
    );

    // A file packed without the primitive table.
    let anim = Animation::new(&kitchen, 400..402).unwrap();
    let file = dir.path().join("plain.oavm");
    let frame = anim.frame(400).unwrap();
    oavm::pack::pack_mesh(
        frame.mesh,
        "kitchen",
        &file,
        &PackOptions::default(),
        &Quiet,
    )
    .unwrap();
    let bytes = std::fs::read(&file).unwrap();
    let out = dir.path().join("never");
    says(
        &err_text(animate(
            &anim,
            &file,
            &opts(Mode::Update, &out, CameraChoice::View),
            &mut |_| {},
        )),
        &["plain.oavm", "no primitive table", "--updatable"],
    );
    assert_eq!(
        std::fs::read(&file).unwrap(),
        bytes,
        "the file is left as it was"
    );
    assert!(!out.exists(), "nothing is written");
    // A missing file, and a depth past the limit.
    says(
        &err_text(animate(
            &anim,
            &dir.path().join("nowhere.oavm"),
            &opts(Mode::Update, &out, CameraChoice::View),
            &mut |_| {},
        )),
        &["nowhere.oavm"],
    );
    let mut o = opts(Mode::Rebuild, &out, CameraChoice::View);
    o.max_depth = 99;
    says(
        &err_text(animate(&anim, &file, &o, &mut |_| {})),
        &["depth of 99"],
    );
    // A camera path the scene does not have.
    let rain = Animation::with_meshes(&view, &pattern, 0..1).unwrap();
    says(
        &err_text(animate(
            &rain,
            &dir.path().join("r.oavm"),
            &opts(Mode::Rebuild, &out, CameraChoice::Path),
            &mut |_| {},
        )),
        &["frame 0", "rain.aff", "no camera path"],
    );
}

/// `oavm-trace --frames`: packs with --pack, writes the numbered images, reports as JSON; a
/// rebuild run writes the same images; usage errors and a file that cannot be updated fail
/// with the cause.
#[test]
fn oavm_trace_frames() {
    let dir = TempDir::new().unwrap();
    let (view, pattern) = rain_frames(&dir.path().join("rain"), 300, "3..5");
    let file = dir.path().join("r.oavm");
    let frames = |extra: &[&str], out: &Path| {
        let mut cmd = bin("oavm-trace");
        cmd.arg(&file)
            .args(["--frames", "3..5", "--view"])
            .arg(&view)
            .args([
                "--frame-meshes",
                &pattern,
                "--width",
                "40",
                "--height",
                "30",
            ])
            .arg("-o")
            .arg(out)
            .args(extra);
        run(&mut cmd)
    };
    let (u, r) = (dir.path().join("u"), dir.path().join("r"));
    let (o, stdout, stderr) = frames(&["--pack", "--json", "--depth", "2"], &u);
    assert!(o.status.success(), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(report["frames"], 2);
    assert_eq!(report["mode"], "update");
    assert_eq!(report["max_depth"], 2);
    assert_eq!(report["packed"]["frame"], 3);
    assert_eq!(report["per_frame"][0]["changed"], 0);
    assert_eq!(report["per_frame"][1]["update"]["moved"], 300 * 8);
    let (o, stdout, stderr) = frames(&["--rebuild", "--depth", "2"], &r);
    assert!(o.status.success(), "{stderr}");
    assert!(
        stdout.contains("2 frames (40x30, rebuilt, depth 2)"),
        "{stdout}"
    );
    for f in [3, 4] {
        let name = frame_image_name(f);
        let image = std::fs::read(u.join(&name)).unwrap();
        assert!(image.starts_with(b"\x89PNG"), "{name}");
        assert!(image == std::fs::read(r.join(&name)).unwrap(), "{name}");
    }

    // Usage errors: exit status 2.
    let (o, _, stderr) = frames(&["--frames", "4..2"], &u);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    let (o, _, stderr) = run(bin("oavm-trace")
        .arg(&file)
        .args(["--frames", "3..5", "--view"])
        .arg(&view)
        .args(["--frame-meshes", &pattern]));
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    says(&stderr, &["--frames needs -o OUT_DIR"]);
    let (o, _, stderr) = frames(&["--pack", "--rebuild"], &u);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    // A file without the primitive table: exit status 1, the cause named.
    let plain = dir.path().join("plain.oavm");
    let (o, _, stderr) = run(bin("oavm-pack")
        .arg(pattern.replace("{}", "00003"))
        .arg(&plain));
    assert!(o.status.success(), "{stderr}");
    let (o, _, stderr) = run(bin("oavm-trace")
        .arg(&plain)
        .args(["--frames", "3..5", "--view"])
        .arg(&view)
        .args(["--frame-meshes", &pattern, "-o"])
        .arg(dir.path().join("p")));
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    says(
        &stderr,
        &["oavm-trace: error", "no primitive table", "--updatable"],
    );
}

#[test]
fn frame_ranges_parse_as_oavm_trace_reads_them() {
    assert_eq!(parse_frames("3..7").unwrap(), 3..7);
    assert_eq!(parse_frames("3..=7").unwrap(), 3..8);
    assert_eq!(parse_frames(" 5 ").unwrap(), 5..6);
    let too_far = format!("0..={}", u64::MAX);
    for bad in [
        "7..3",
        "4..4",
        "a..3",
        "",
        "1..b",
        &too_far,
        &u64::MAX.to_string(),
    ] {
        assert!(parse_frames(bad).is_err(), "{bad:?}");
    }
    let e = parse_frames("7..3").unwrap_err().to_string();
    assert!(e.contains("the range is empty"), "{e}");
}
