//! The Rain scene generator (`tools/rain.rs`, the `rain` example): its frames are deterministic,
//! keep the primitive-id space of every frame the same, give ball `i` the same motion whatever
//! the number of balls, stay inside the documented box, and parse with the crate's PLY loader;
//! bad arguments are errors, never panics.
//!
//! Cargo builds no example for an integration test and gives it no `CARGO_BIN_EXE_` path for
//! one, so this test compiles the example's source as a module (`#[path]`) and calls it: the
//! same code as the binary, from argument parsing (`Args::try_parse_from`) and validation
//! (`Config::new`) to the files (`write_all`), minus `main`, which only hands `run`'s error to
//! the binaries' shared `main_with` (message, exit status 1). Frames are mostly written to
//! memory (`write_frame`) and parsed with `oavm::mesh::parse_ply`; one run writes a directory
//! and reads it back with `oavm::mesh::load` and `load_aff`.

#[allow(dead_code)]
use crate::rain_example as rain;

use clap::Parser;
use oavm::Mesh;
use rain::{Args, BOX_MAX, BOX_MIN, Config, Shape};

fn config(args: &[&str]) -> Config {
    let mut all = vec!["rain", "--out", "unused"];
    all.extend_from_slice(args);
    let parsed = Args::try_parse_from(&all).unwrap_or_else(|e| panic!("{all:?}: {e}"));
    Config::new(&parsed).unwrap_or_else(|e| panic!("{all:?}: {e}"))
}

fn frame_bytes(c: &Config, frame: u64) -> Vec<u8> {
    let mut v = Vec::new();
    let n = rain::write_frame(&mut v, c, frame).expect("writing to memory");
    assert_eq!(n, v.len() as u64, "write_frame reports the bytes it wrote");
    v
}

fn frame_mesh(c: &Config, frame: u64) -> Mesh {
    let bytes = frame_bytes(c, frame);
    oavm::mesh::parse_ply(&bytes, &rain::frame_name(frame)).unwrap_or_else(|e| panic!("{e}"))
}

fn faces(shape: Shape) -> usize {
    shape.faces().len()
}

/// The corners of ball `i`'s triangles.
fn ball(m: &Mesh, shape: Shape, i: usize) -> Vec<[[f32; 3]; 3]> {
    let t = faces(shape);
    (2 + i * t..2 + (i + 1) * t)
        .map(|p| m.triangle(p))
        .collect()
}

#[test]
fn the_same_arguments_give_the_same_bytes() {
    for shape in ["octahedron", "icosahedron"] {
        let c = config(&[
            "--balls", "500", "--seed", "7", "--shape", shape, "--frames", "0",
        ]);
        for frame in [0, 1, 250, 99_999] {
            assert_eq!(frame_bytes(&c, frame), frame_bytes(&c, frame), "{shape}");
        }
        let other_seed = config(&[
            "--balls", "500", "--seed", "8", "--shape", shape, "--frames", "0",
        ]);
        assert_ne!(
            frame_bytes(&c, 3),
            frame_bytes(&other_seed, 3),
            "{shape}: the seed matters"
        );
    }
}

#[test]
fn frames_share_the_ground_and_the_primitive_ids_and_move_every_ball() {
    for shape in [Shape::Octahedron, Shape::Icosahedron] {
        let c = config(&["--balls", "1000", "--shape", shape.name(), "--frames", "0"]);
        let first = frame_mesh(&c, 0);
        let t = faces(shape);
        assert_eq!(first.triangles.len(), 2 + 1000 * t + 1);
        assert_eq!(first.positions.len(), 7 + 1000 * shape.vertices().len());
        for frame in [1, 2, 25, 1000, 123_457] {
            let m = frame_mesh(&c, frame);
            // The same triangles (indices) in every frame: only the vertices move.
            assert_eq!(m.triangles, first.triangles, "{shape:?} frame {frame}");
            for p in [0, 1, m.triangles.len() - 1] {
                assert_eq!(
                    m.triangle(p),
                    first.triangle(p),
                    "{shape:?} frame {frame}: the ground and the marker do not move"
                );
            }
            for i in 0..1000 {
                assert_ne!(
                    ball(&m, shape, i),
                    ball(&first, shape, i),
                    "{shape:?} frame {frame}: ball {i} has not moved"
                );
            }
        }
        // Consecutive frames: every ball moved by a small step (no wrap) or wrapped to the top.
        let (a, b) = (frame_mesh(&c, 40), frame_mesh(&c, 41));
        let mut wrapped = 0;
        for i in 0..1000 {
            let (pa, pb) = (ball(&a, shape, i)[0][0], ball(&b, shape, i)[0][0]);
            let dy = pb[1] - pa[1];
            if dy > 0.0 {
                wrapped += 1;
                assert!(dy > 90.0, "ball {i} went up by {dy} without wrapping");
            } else {
                assert!(
                    (0.2..0.5).contains(&-dy),
                    "ball {i} fell by {} in a frame",
                    -dy
                );
            }
            assert!((pb[0] - pa[0]).abs() < 0.1 && (pb[2] - pa[2]).abs() < 0.1);
        }
        assert!(wrapped < 20, "{wrapped} of 1000 balls wrapped in one frame");
    }
}

#[test]
fn ball_i_does_not_depend_on_the_number_of_balls() {
    for shape in [Shape::Octahedron, Shape::Icosahedron] {
        let small = config(&["--balls", "1000", "--shape", shape.name(), "--frames", "0"]);
        let large = config(&["--balls", "2000", "--shape", shape.name(), "--frames", "0"]);
        for frame in [0, 17, 5000] {
            let (s, l) = (frame_mesh(&small, frame), frame_mesh(&large, frame));
            let t = faces(shape);
            assert_eq!(s.triangles[..2 + 1000 * t], l.triangles[..2 + 1000 * t]);
            for i in 0..1000 {
                assert_eq!(ball(&s, shape, i), ball(&l, shape, i), "{shape:?} ball {i}");
            }
        }
    }
}

#[test]
fn every_frame_spans_exactly_the_box_with_the_balls_strictly_inside() {
    let lo = BOX_MIN.map(|x| x as f32);
    let hi = BOX_MAX.map(|x| x as f32);
    for (shape, radius) in [
        (Shape::Octahedron, "0.1"),
        (Shape::Icosahedron, "0.1"),
        (Shape::Octahedron, "5"),
    ] {
        let c = config(&[
            "--balls",
            "2000",
            "--shape",
            shape.name(),
            "--radius",
            radius,
            "--frames",
            "0",
        ]);
        let frames = (0..300)
            .step_by(7)
            .chain([1_000_003, u32::MAX as u64, u64::MAX / 3]);
        for frame in frames {
            let m = frame_mesh(&c, frame);
            let corners = m.corners();
            let (mut mlo, mut mhi) = ([f32::MAX; 3], [f32::MIN; 3]);
            for tri in &corners {
                for v in tri {
                    for k in 0..3 {
                        mlo[k] = mlo[k].min(v[k]);
                        mhi[k] = mhi[k].max(v[k]);
                    }
                }
            }
            assert_eq!(
                (mlo, mhi),
                (lo, hi),
                "{shape:?} frame {frame}: the mesh bounds are the box"
            );
            for tri in &corners[2..corners.len() - 1] {
                for v in tri {
                    for k in 0..3 {
                        assert!(
                            v[k] > lo[k] && v[k] < hi[k],
                            "{shape:?} r {radius} frame {frame}: {v:?} is not inside the box"
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn the_shapes_are_closed_wound_outward_and_on_the_sphere() {
    for shape in [Shape::Octahedron, Shape::Icosahedron] {
        let v = shape.vertices();
        assert_eq!(v.len(), shape.vertex_count());
        for p in &v {
            let len = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-12, "{shape:?}: |{p:?}| = {len}");
        }
        let mut edges = std::collections::HashMap::new();
        for f in shape.faces() {
            let [a, b, c] = f.map(|i| v[i as usize]);
            let (u, w) = (
                [0, 1, 2].map(|k| b[k] - a[k]),
                [0, 1, 2].map(|k| c[k] - a[k]),
            );
            let n = [
                u[1] * w[2] - u[2] * w[1],
                u[2] * w[0] - u[0] * w[2],
                u[0] * w[1] - u[1] * w[0],
            ];
            let centroid = [0, 1, 2].map(|k| a[k] + b[k] + c[k]);
            assert!(
                (0..3).map(|k| n[k] * centroid[k]).sum::<f64>() > 0.0,
                "{shape:?} {f:?}"
            );
            for k in 0..3 {
                *edges.entry((f[k], f[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        // Closed and consistently wound: every directed edge once, and its reverse once.
        for (&(a, b), &n) in &edges {
            assert_eq!(n, 1, "{shape:?} edge {a}-{b}");
            assert_eq!(edges.get(&(b, a)), Some(&1), "{shape:?} edge {b}-{a}");
        }
        assert_eq!(edges.len(), 3 * shape.faces().len());
    }
}

#[test]
fn a_run_writes_frames_the_loader_reads_and_a_view_that_parses() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let out = dir.path().join("new/rain");
    let args = Args::try_parse_from([
        "rain",
        "--balls",
        "300",
        "--seed",
        "3",
        "--frames",
        "4..=6",
        "--shape",
        "icosahedron",
        "--out",
        out.to_str().expect("utf-8 path"),
    ])
    .expect("arguments");
    let c = Config::new(&args).expect("config");
    let mut seen = Vec::new();
    let report = rain::write_all(&c, |f| seen.push(f.frame)).expect("write");
    assert_eq!(seen, [4, 5, 6]);
    assert_eq!(report.triangles_per_frame, 2 + 300 * 20 + 1);
    let mut names: Vec<_> = std::fs::read_dir(&out)
        .expect("output directory")
        .map(|e| e.expect("entry").file_name().into_string().expect("name"))
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "rain.aff",
            "rain_00004.ply",
            "rain_00005.ply",
            "rain_00006.ply"
        ]
    );
    for f in &report.frames {
        let bytes = std::fs::read(&f.path).expect("frame");
        assert_eq!(bytes.len() as u64, f.bytes);
        assert_eq!(
            bytes,
            frame_bytes(&c, f.frame),
            "the file is what write_frame writes"
        );
        let m = oavm::mesh::load(&f.path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(m.triangles.len() as u64, report.triangles_per_frame);
    }
    let scene = oavm::mesh::load_aff(&report.view, None).unwrap_or_else(|e| panic!("{e}"));
    let v = scene.view.expect("a `v` block");
    assert_eq!(v.resolution, (1024, 768));
    assert_eq!(scene.mesh.triangles.len(), 2, "the ground quad");
    let light = scene.lights.first().expect("a light");
    assert!(
        light[1] > BOX_MAX[1],
        "the light is above the box: {light:?}"
    );
    // The camera is outside the box, looking into it.
    assert!((0..3).any(|k| v.from[k] < BOX_MIN[k] || v.from[k] > BOX_MAX[k]));
    assert!((0..3).all(|k| v.at[k] > BOX_MIN[k] && v.at[k] < BOX_MAX[k]));
}

/// The message of the error `Config::new` (or, for `frames`, parsing) gives for `args`.
fn refused(args: &[&str]) -> String {
    let mut all = vec!["rain", "--out", "unused"];
    all.extend_from_slice(args);
    let parsed = Args::try_parse_from(&all).unwrap_or_else(|e| panic!("{all:?}: {e}"));
    match Config::new(&parsed) {
        Ok(c) => panic!("{all:?} accepted: {c:?}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_arguments_are_clear_errors() {
    fn with<'a>(extra: &[&'a str]) -> Vec<&'a str> {
        [&["--frames", "0"][..], extra].concat()
    }
    assert!(refused(&with(&["--balls", "0"])).contains("at least 1"));
    for shape in [Shape::Octahedron, Shape::Icosahedron] {
        let max = rain::max_balls(shape);
        // The largest scene has fewer than 0xFFFFFFFF triangles (what oavm::mesh accepts).
        assert!(2 + max * faces(shape) as u64 + 1 < u32::MAX as u64);
        assert!(2 + (max + 1) * faces(shape) as u64 + 1 >= u32::MAX as u64);
        let ok = max.to_string();
        let c = config(&with(&["--balls", &ok, "--shape", shape.name()]));
        assert!(c.vertices() <= u32::MAX as u64 + 1);
        let over = (max + 1).to_string();
        let e = refused(&with(&["--balls", &over, "--shape", shape.name()]));
        assert!(e.contains("u32 primitive ids"), "{e}");
    }
    for r in ["0", "-1", "NaN", "inf", "5.01", "-0"] {
        let e = refused(&with(&["--balls", "1", "--radius", r]));
        assert!(e.contains("--radius"), "{r}: {e}");
    }
    for fps in ["0", "-25", "NaN", "inf"] {
        let e = refused(&with(&["--balls", "1", "--fps", fps]));
        assert!(e.contains("--fps"), "{fps}: {e}");
    }
    for frames in [
        "5..5",
        "7..3",
        "a..b",
        "",
        "..",
        "3..=2",
        "1.5",
        "18446744073709551615..=18446744073709551615",
    ] {
        let e = refused(&["--balls", "1", "--frames", frames]);
        assert!(e.contains("--frames"), "{frames:?}: {e}");
    }
    assert_eq!(rain::parse_frames("3..5").expect("range"), (3, 5));
    assert_eq!(rain::parse_frames("3..=5").expect("range"), (3, 6));
    assert_eq!(rain::parse_frames("9").expect("one"), (9, 10));
    // Not numbers, or missing: clap's usage errors (exit status 2 from the binary).
    for args in [
        &["rain", "--out", "d", "--frames", "0", "--balls", "ten"][..],
        &["rain", "--out", "d", "--frames", "0"],
        &[
            "rain", "--out", "d", "--frames", "0", "--balls", "1", "--shape", "cube",
        ],
    ] {
        assert!(Args::try_parse_from(args).is_err(), "{args:?}");
    }
}

#[test]
fn an_output_directory_that_cannot_be_made_is_an_error_naming_it() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let file = dir.path().join("a-file");
    std::fs::write(&file, b"not a directory").expect("write");
    for out in [file.clone(), file.join("sub")] {
        let c = config(&["--balls", "1", "--frames", "0"]);
        let c = Config {
            out: out.clone(),
            ..c
        };
        let e = rain::write_all(&c, |_| {}).expect_err("not a directory");
        let e = e.to_string();
        assert!(e.contains(&*out.to_string_lossy()), "{e}");
        assert!(e.contains("cannot create the output directory"), "{e}");
    }
    assert_eq!(std::fs::read(&file).expect("read"), b"not a directory");
}
