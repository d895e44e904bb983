//! The Whitted-style renderer (`oavm::render::render_shaded`) with the looks of BART scenes and
//! of plain meshes: shadows against an f64 reference, mirrors, refraction by Snell's law
//! (measured against the slab displacement), total internal reflection, determinism over
//! threads and tile orders, the ray counts' identities, defensive reading of odd materials, and
//! `oavm-trace --shade`.
//!
//! The Cornell box and the kitchen come from `../shared/scenes`; a missing file fails.

use crate::common;

use crate::common::{bin, build_scene, run, shared_scene};
use oavm::geom::reference;
use oavm::logical::{Order, SceneOptions};
use oavm::mesh::aff::AffMaterial;
use oavm::mesh::{AffScene, parse_aff};
use oavm::physical::AlignedBytes;
use oavm::rays::{Bounds, Camera, SHADOW_EPSILON, default_light};
use oavm::render::{
    DEFAULT_MAX_DEPTH, DEFAULT_SIZE, Image, Look, MAX_DEPTH_LIMIT, OFFSET, PointLight,
    ShadedOptions, ShadedShot, ShadedStats, Shot, ShotSpec, render_shaded,
};
use oavm::{BuildOptions, Mesh, Ray, Scene};

/// A scene parsed from AFF text (no includes).
fn aff(text: &str) -> AffScene {
    parse_aff(text.as_bytes(), "mem.aff", None).unwrap_or_else(|e| panic!("{e}"))
}

/// The packed bytes of `mesh`.
fn pack(mesh: &Mesh) -> AlignedBytes {
    let (parts, _) =
        oavm::pack::build(mesh, &BuildOptions::default(), &oavm::pack::Quiet).expect("build");
    oavm::pack::encode(&parts).expect("encode")
}

/// The camera of a scene's `v` block.
fn view_camera(s: &AffScene) -> Camera {
    let v = s.view.expect("a viewpoint");
    Camera::look_at(v.from, v.at, v.up, v.angle_deg).expect("camera")
}

fn shade<D: AsRef<[u8]> + oavm::logical::BlockSource>(
    scene: &Scene<D>,
    opts: &ShadedOptions,
    look: &Look,
) -> (Image, ShadedStats) {
    render_shaded(scene, opts, look).unwrap_or_else(|e| panic!("{e}"))
}

/// An AFF scene's mesh built in memory and rendered from its viewpoint with its look, at
/// `w` x `h`, with `edit` applied to the options.
fn render_aff(
    s: &AffScene,
    w: u32,
    h: u32,
    edit: impl FnOnce(&mut ShadedOptions),
) -> (Image, ShadedStats) {
    let scene = build_scene(&s.mesh, &BuildOptions::default());
    let mut opts = ShadedOptions::new(w, h, view_camera(s));
    edit(&mut opts);
    shade(&scene, &opts, &Look::from_aff(s))
}

fn pixel(img: &Image, x: u32, y: u32) -> [u8; 3] {
    let i = 3 * (y * img.width + x) as usize;
    [img.rgb[i], img.rgb[i + 1], img.rgb[i + 2]]
}

/// The identities every render's counts keep.
#[track_caller]
fn check_counts(s: &ShadedStats, lights: u64, shadows: bool) {
    assert_eq!(s.primary.rays, s.width as u64 * s.height as u64);
    assert_eq!(
        s.rays,
        s.primary.rays + s.shadow.rays + s.reflection.rays + s.refraction.rays
    );
    assert!(s.hits <= s.primary.rays && s.hits <= s.surface_hits);
    assert!(s.surface_hits <= s.primary.rays + s.reflection.rays + s.refraction.rays);
    if shadows {
        assert_eq!(
            s.shadow.rays + s.facing_away,
            s.surface_hits * lights,
            "{s:?}"
        );
    } else {
        assert_eq!(s.shadow.rays, 0);
    }
    assert!(s.shadowed <= s.shadow.rays);
}

/// The six faces of the cube `[-0.5, 0.5]^3` as AFF quads, counter-clockwise seen from outside
/// (outward geometric normals, which decide entering and leaving a refractive object).
const CUBE: &str = "\
    p 4  -0.5 -0.5 0.5   0.5 -0.5 0.5   0.5 0.5 0.5   -0.5 0.5 0.5\n\
    p 4  -0.5 -0.5 -0.5  -0.5 0.5 -0.5  0.5 0.5 -0.5  0.5 -0.5 -0.5\n\
    p 4  0.5 -0.5 -0.5   0.5 0.5 -0.5   0.5 0.5 0.5   0.5 -0.5 0.5\n\
    p 4  -0.5 -0.5 -0.5  -0.5 -0.5 0.5  -0.5 0.5 0.5  -0.5 0.5 -0.5\n\
    p 4  -0.5 0.5 -0.5   -0.5 0.5 0.5   0.5 0.5 0.5   0.5 0.5 -0.5\n\
    p 4  -0.5 -0.5 -0.5  0.5 -0.5 -0.5  0.5 -0.5 0.5  -0.5 -0.5 0.5\n";

#[test]
fn the_test_cube_faces_outward() {
    let s = aff(CUBE);
    assert_eq!(s.mesh.triangles.len(), 12);
    for i in 0..12 {
        let [a, b, c] = s.mesh.triangle(i).map(|p| p.map(f64::from));
        let e1 = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let e2 = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let centre = [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0);
        assert!(
            n.iter().zip(centre).map(|(n, c)| n * c).sum::<f64>() > 0.0,
            "face {i}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Shadows: the Cornell box with the default look, against the f64 reference

/// Every pixel the f64 reference puts in shadow (its closest hit faces the light, clearly, and
/// the segment to the light meets a triangle) is darker with shadows than without; every
/// pixel it puts in light is the same; the counts hold their identities.
#[test]
fn cornell_box_shadows_darken_the_pixels_the_reference_shadows() {
    let path = shared_scene("cornell_box/CornellBox-Original.obj");
    let mesh = oavm::mesh::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let tris = common::corners(&mesh);
    let bounds = common::bounds(&mesh);
    let scene = build_scene(&mesh, &BuildOptions::default());
    let look = Look::plain(&bounds);
    assert_eq!(look.lights.len(), 1);
    let light = look.lights[0].position;
    assert_eq!(light, default_light(&bounds).map(f64::from));
    let camera = Camera::framing(&bounds);
    let (w, h) = (160, 120);
    let opts = ShadedOptions::new(w, h, camera);
    let (lit, s) = shade(&scene, &opts, &look);
    let (unshadowed, s_off) = shade(
        &scene,
        &ShadedOptions {
            shadows: false,
            ..opts
        },
        &look,
    );
    check_counts(&s, 1, true);
    check_counts(&s_off, 1, false);
    // One white diffuse material: no secondary rays.
    assert_eq!(s.reflection.rays + s.refraction.rays, 0);
    assert_eq!(s.surface_hits, s.hits);
    assert!(s.hits > (w * h / 2) as u64, "{s:?}");

    // The renderer's offset: OFFSET times the larger of the diagonal and the largest
    // coordinate.
    let far = bounds
        .min
        .iter()
        .chain(&bounds.max)
        .fold(0f64, |m, c| m.max((*c as f64).abs()));
    let lift = OFFSET * bounds.diagonal().max(far);
    let pixels = camera.pixels(w, h);
    let (mut in_shadow, mut in_light) = (0, 0);
    for y in 0..h {
        for x in 0..w {
            let ray = pixels.ray(x, y);
            let hit = reference::closest(&tris, &ray);
            if !hit.is_hit() || reference::grazes(&tris, &ray) {
                assert!(hit.is_hit() || pixel(&lit, x, y) == pixel(&unshadowed, x, y));
                continue;
            }
            let p = ray.at(hit.t as f64);
            let [a, b, c] = tris[hit.prim as usize].map(|v| v.map(f64::from));
            let n = cross(sub(b, a), sub(c, a));
            let n = scale(n, 1.0 / dot(n, n).sqrt());
            let n = if dot(n, ray.dir.map(f64::from)) > 0.0 {
                scale(n, -1.0)
            } else {
                n
            };
            let to_light = sub(light, p);
            let cos = dot(n, to_light) / dot(to_light, to_light).sqrt();
            if cos < 0.1 {
                continue;
            }
            // The reference's shadow ray, lifted off the surface as the renderer lifts its
            // own, short of the light.
            let o = [0, 1, 2].map(|k| p[k] + n[k] * lift);
            let segment = Ray::new(
                o.map(|c| c as f32),
                [0, 1, 2].map(|k| (light[k] - o[k]) as f32),
                0.0,
                1.0 - SHADOW_EPSILON,
            );
            if reference::grazes(&tris, &segment) {
                continue;
            }
            let (on, off) = (pixel(&lit, x, y), pixel(&unshadowed, x, y));
            if reference::occluded(&tris, &segment) {
                in_shadow += 1;
                assert!(
                    on.iter().zip(off).all(|(a, b)| *a <= b) && on != off,
                    "pixel ({x}, {y}) is in shadow: {on:?} with shadows, {off:?} without"
                );
            } else {
                in_light += 1;
                assert_eq!(on, off, "pixel ({x}, {y}) is lit");
            }
        }
    }
    eprintln!("{in_shadow} pixels in shadow, {in_light} lit");
    assert!(
        in_shadow > 1000 && in_light > 1000,
        "{in_shadow} / {in_light}"
    );
    // The renderer's own count of shadowed points is the reference's, to the pixels left out
    // as grazing or facing away.
    assert!(
        s.shadowed >= in_shadow as u64,
        "{} < {in_shadow}",
        s.shadowed
    );
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    a.map(|x| x * s)
}

// ---------------------------------------------------------------------------------------------
// Mirrors

/// A mirror in front of the camera and a red wall behind it: the mirror shows the wall.
const MIRROR: &str = "\
    b 0 0 1\n\
    am 0 0 0\n\
    v from 0 0 0 at 0 0 -1 up 0 1 0 angle 40 hither 0.01 resolution 160 120\n\
    l 0 0 1\n\
    fm 0 0 0  0 0 0  1 1 1  0 0 0\n\
    p 4  -1 -1 -5  1 -1 -5  1 1 -5  -1 1 -5\n\
    f 1 0 0 1 0 0 0 1\n\
    p 4  -10 -10 5  -10 10 5  10 10 5  10 -10 5\n";

#[test]
fn a_mirror_shows_the_red_wall_behind_the_camera() {
    let s = aff(MIRROR);
    assert_eq!(s.material_of, vec![1, 1, 2, 2]);
    let (img, st) = render_aff(&s, 160, 120, |_| {});
    // The mirror (depth 1 reflection of the lit red wall), and around it the blue background.
    assert_eq!(pixel(&img, 80, 60), [255, 0, 0]);
    assert_eq!(pixel(&img, 2, 2), [0, 0, 255]);
    check_counts(&st, 1, true);
    // Every primary hit is the mirror, reflected once onto the wall, which reflects nothing.
    assert!(st.hits > 1000);
    assert_eq!(st.reflection.rays, st.hits);
    assert_eq!(st.surface_hits, 2 * st.hits);
    assert_eq!(st.refraction.rays, 0);

    // Without bounces the mirror is black (no diffuse, no ambient, no highlight).
    let (img0, st0) = render_aff(&s, 160, 120, |o| o.max_depth = 0);
    assert_eq!(pixel(&img0, 80, 60), [0, 0, 0]);
    assert_eq!((st0.reflection.rays, st0.depth_limited), (0, st0.hits));
    // A grey diffuse quad instead of the mirror shows grey.
    let grey = aff(&MIRROR.replace("fm 0 0 0  0 0 0  1 1 1  0 0 0", "f 1 1 1 0.5 0 0 0 1"));
    let (img_g, _) = render_aff(&grey, 160, 120, |_| {});
    let [r, g, b] = pixel(&img_g, 80, 60);
    assert!(r == g && g == b && r > 100, "{:?}", [r, g, b]);
    // A half-silvered mirror shows the wall at half its brightness; a weight under the
    // minimum casts no ray.
    let half = aff(&MIRROR.replace("1 1 1  0 0 0\n", "0.5 0.5 0.5  0 0 0\n"));
    let (img_h, _) = render_aff(&half, 160, 120, |_| {});
    let [r, g, b] = pixel(&img_h, 80, 60);
    assert!(
        (127..=128).contains(&r) && g == 0 && b == 0,
        "{:?}",
        [r, g, b]
    );
    let (img_w, st_w) = render_aff(&half, 160, 120, |o| o.min_weight = 0.6);
    assert_eq!(pixel(&img_w, 80, 60), [0, 0, 0]);
    assert_eq!((st_w.reflection.rays, st_w.weight_limited), (0, st_w.hits));
}

// ---------------------------------------------------------------------------------------------
// Refraction

/// A wall red left of x = 0 and green right of it, seen straight on from far away through a
/// slab of glass 2 thick turned 45 degrees about y, with transmittance `t` and index `ior`.
fn slab(t: f64, ior: f64) -> AffScene {
    aff(&format!(
        "b 0 0 0\nam 1 1 1\n\
         v from 0 0 100 at 0 0 0 up 0 1 0 angle 4 hither 0.01 resolution 160 120\n\
         l 0 0 50\n\
         f 1 0 0 1 0 0 0 1\n\
         p 4  -20 -20 -5  0 -20 -5  0 20 -5  -20 20 -5\n\
         f 0 1 0 1 0 0 0 1\n\
         p 4  0 -20 -5  20 -20 -5  20 20 -5  0 20 -5\n\
         fm 0 0 0  0 0 0  0 0 0  0 {t} {ior}\n\
         xs 8 8 2  0 1 0 45  0 0 0 {{\n{CUBE}}}\n"
    ))
}

/// The first column of the middle row, from column 50, that shows more green than red (the
/// middle of the image looks through the slab's large faces; left of column 50 and right of
/// 130 are its narrow ends, which bend the wall away).
fn boundary(img: &Image) -> u32 {
    (50..130)
        .find(|&x| {
            let [r, g, _] = pixel(img, x, img.height / 2);
            g > r
        })
        .expect("a green pixel")
}

#[test]
fn a_glass_slab_transmits_and_shifts_the_view_by_snells_law() {
    let (w, h) = (160, 120);
    // Index 1: the rays pass straight, the boundary is at the image's centre; the slab's own
    // shading is black, so the wall shows at full colour.
    let (straight, st1) = render_aff(&slab(1.0, 1.0), w, h, |_| {});
    assert_eq!(boundary(&straight), w / 2);
    assert_eq!(pixel(&straight, 60, 60), [255, 0, 0]);
    assert_eq!(pixel(&straight, 120, 60), [0, 255, 0]);
    check_counts(&st1, 1, true);
    // Most pixels look through the slab: two refractions each.
    assert!(st1.refraction.rays > (w * h) as u64, "{st1:?}");
    assert_eq!(st1.total_internal_reflections, 0);

    // Index 1.5: a ray entering at 45 degrees leaves parallel to itself, displaced sideways by
    // d sin(i - r) / cos(r) for a slab d thick (sin r = sin i / 1.5), toward -x: the wall's
    // boundary shows that far to the right.
    let (bent, st) = render_aff(&slab(1.0, 1.5), w, h, |_| {});
    check_counts(&st, 1, true);
    let i = 45f64.to_radians();
    let r = (i.sin() / 1.5).asin();
    let shift = 2.0 * (i - r).sin() / r.cos();
    // Pixels at the wall, 105 from the camera.
    let px = 2.0 * 105.0 * 2f64.to_radians().tan() / h as f64;
    let expected = w as f64 / 2.0 + shift / px;
    let got = boundary(&bent) as f64;
    assert!(
        (got - expected).abs() <= 1.5,
        "the boundary shows at column {got}, Snell's law puts it at {expected:.1}"
    );
    // Both sides still show through.
    assert_eq!(pixel(&bent, 60, 60), [255, 0, 0]);
    assert_eq!(pixel(&bent, 120, 60), [0, 255, 0]);

    // Transmittance 0.5 at each of the two faces: a quarter of the wall's colour.
    let (dim, _) = render_aff(&slab(0.5, 1.5), w, h, |_| {});
    assert_eq!(pixel(&dim, 60, 60), [64, 0, 0]);
    // Not enough depth to get through both faces: black.
    let (shallow, st_s) = render_aff(&slab(1.0, 1.5), w, h, |o| o.max_depth = 1);
    assert_eq!(pixel(&shallow, 60, 60), [0, 0, 0]);
    assert!(st_s.depth_limited > 0);
}

/// From inside a glass cube, rays meeting a face beyond the critical angle (41.8 degrees for
/// index 1.5) are reflected; the ray straight ahead leaves and shows the background.
#[test]
fn total_internal_reflection_inside_glass() {
    let cube = |ior: f64| {
        aff(&format!(
            "b 0 0 1\nam 0 0 0\n\
             v from 0 0 0 at 0 0 -1 up 0 1 0 angle 100 hither 0.01 resolution 80 60\n\
             fm 0 0 0  0 0 0  0 0 0  0 1 {ior}\n\
             xs 10 10 10  0 1 0 0  0 0 0 {{\n{CUBE}}}\n"
        ))
    };
    let (img, st) = render_aff(&cube(1.5), 80, 60, |_| {});
    assert_eq!(pixel(&img, 40, 30), [0, 0, 255]);
    assert!(st.total_internal_reflections > 100, "{st:?}");
    // Column 63 of the middle row meets the far face at 43 degrees: reflected (onto the side
    // face at 47 degrees, reflected again...), it never gets out within the depth. Were the
    // reflection missed, its NaN direction would miss everything and show the background.
    assert_ne!(pixel(&img, 63, 30), [0, 0, 255]);
    check_counts(&st, 0, true);
    let (img1, st1) = render_aff(&cube(1.0), 80, 60, |_| {});
    assert_eq!(st1.total_internal_reflections, 0);
    assert!(img1.rgb.chunks(3).all(|p| p == [0, 0, 255]));
}

// ---------------------------------------------------------------------------------------------
// The kitchen: determinism, counts, materials

#[test]
fn kitchen_renders_the_same_on_one_and_two_threads_and_in_any_order() {
    let path = shared_scene("bart/kitchen/kitchen.aff");
    let s = oavm::mesh::load_aff(&path, None).unwrap_or_else(|e| panic!("{e}"));
    let bytes = pack(&s.mesh);
    let look = Look::from_aff(&s);
    assert_eq!(look.lights.len(), 6);
    let opts = ShadedOptions::new(160, 120, view_camera(&s));
    assert_eq!(opts.max_depth, DEFAULT_MAX_DEPTH);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let render = |threads: usize, order: Order| {
        let scene = Scene::from_bytes_with(
            bytes.clone(),
            "kitchen.oavm",
            &SceneOptions {
                threads,
                ..Default::default()
            },
        )
        .expect("open");
        assert_eq!(scene.threads(), threads);
        pool.install(|| shade(&scene, &ShadedOptions { order, ..opts }, &look))
    };
    let (one, s1) = render(1, Order::Morton);
    let (two, s2) = render(2, Order::Morton);
    let (rows, s3) = render(2, Order::None);
    assert!(one.rgb == two.rgb, "1 and 2 threads differ");
    assert!(one.rgb == rows.rgb, "tile orders differ");
    for st in [&s2, &s3] {
        assert_eq!(
            (st.rays, st.surface_hits, st.shadowed, st.reflection.rays),
            (s1.rays, s1.surface_hits, s1.shadowed, s1.reflection.rays)
        );
    }
    check_counts(&s1, 6, true);
    // The sink and the marble reflect; some lamps are hidden from some points.
    assert!(s1.reflection.rays > 1000, "{s1:?}");
    assert!(s1.shadowed > 1000 && s1.shadowed < s1.shadow.rays);
    // The scene's materials matter: the same frame with one white material differs.
    let plain = Look {
        materials: vec![AffMaterial::DEFAULT],
        material_of: Vec::new(),
        ..look.clone()
    };
    let scene = Scene::from_bytes(bytes.clone(), "kitchen.oavm").expect("open");
    let (white, sw) = shade(&scene, &opts, &plain);
    assert!(white.rgb != one.rgb);
    assert_eq!(sw.reflection.rays + sw.refraction.rays, 0);
    // Without bounces the counts say why.
    let (_, s0) = shade(
        &scene,
        &ShadedOptions {
            max_depth: 0,
            ..opts
        },
        &look,
    );
    assert_eq!(s0.reflection.rays + s0.refraction.rays, 0);
    assert!(s0.depth_limited > 0);
}

// ---------------------------------------------------------------------------------------------
// Odd inputs

#[test]
fn odd_looks_and_options_never_panic() {
    let s = aff(MIRROR);
    let scene = build_scene(&s.mesh, &BuildOptions::default());
    let camera = view_camera(&s);
    let opts = ShadedOptions::new(32, 24, camera);
    // Materials with NaN, infinite, negative values; indices beyond the lists; a light at
    // infinity.
    let bad = AffMaterial {
        ambient: [f32::NAN, -1.0, f32::INFINITY],
        diffuse: [f32::INFINITY; 3],
        specular: [2.0, f32::NAN, -3.0],
        shine: f32::NAN,
        transmittance: 7.0,
        ior: -1.0,
    };
    let look = Look {
        materials: vec![bad],
        material_of: vec![0, 5, 0],
        lights: vec![
            PointLight {
                position: [0.0, 0.0, 1.0],
                colour: [f32::NAN, 1.0, -1.0],
            },
            PointLight {
                position: [f64::INFINITY, 0.0, 0.0],
                colour: [1.0; 3],
            },
        ],
        background: [f32::NAN, 2.0, -1.0],
        ambient: [1.0; 3],
    };
    let (img, st) = shade(&scene, &opts, &look);
    assert_eq!(img.rgb.len(), 32 * 24 * 3);
    // The light at infinity is left out.
    check_counts(&st, 1, true);
    // Primitive 1 names material 5, which does not exist: the default; primitive 3 is beyond
    // `material_of`: the first material.
    assert_eq!(look.material(1), &AffMaterial::DEFAULT);
    assert!(std::ptr::eq(look.material(3), &look.materials[0]));
    assert_eq!(
        Look::plain(&Bounds::of_points([[0.0; 3]])).material(7),
        &AffMaterial::DEFAULT
    );

    for (o, words) in [
        (
            ShadedOptions {
                max_depth: MAX_DEPTH_LIMIT + 1,
                ..opts
            },
            "at most",
        ),
        (
            ShadedOptions {
                min_weight: f64::NAN,
                ..opts
            },
            "minimum ray weight",
        ),
        (ShadedOptions { width: 0, ..opts }, "image size"),
    ] {
        let e = render_shaded(&scene, &o, &look).map(|_| ()).unwrap_err();
        assert!(e.to_string().contains(words), "{e}");
    }
}

// ---------------------------------------------------------------------------------------------
// oavm-trace --shade

#[test]
fn oavm_trace_shades_a_scene_as_the_library_does() {
    let dir = tempfile::tempdir().unwrap();
    let scene_path = dir.path().join("mirror.aff");
    // A blinking triangle, so that two times have different triangles.
    let text = format!(
        "{MIRROR}x blink {{ p 3 5 5 -20 6 5 -20 5 6 -20 }}\nk blink {{ visibility 2  1 0  2 1 }}\n"
    );
    std::fs::write(&scene_path, &text).unwrap();
    let file = dir.path().join("mirror.oavm");
    common::pack(&scene_path, &file, &[]);
    let png = dir.path().join("m.png");
    let (o, out, err) = run(bin("oavm-trace")
        .arg(&file)
        .arg("--view")
        .arg(&scene_path)
        .args(["--shade", "--depth", "3", "--json", "--threads", "2", "-o"])
        .arg(&png));
    assert!(o.status.success(), "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["shading"], "whitted");
    assert_eq!(v["max_depth"], 3);
    assert_eq!(
        (v["lights"].as_u64(), v["materials"].as_u64()),
        (Some(1), Some(3))
    );
    let r = &v["render"];
    assert_eq!(
        (r["width"].as_u64(), r["height"].as_u64()),
        (Some(160), Some(120))
    );
    // The library's render of the same scene counts the same rays.
    let s = parse_aff(text.as_bytes(), "mem.aff", None).unwrap();
    let (_, st) = render_aff(&s, 160, 120, |o| o.max_depth = 3);
    assert_eq!(v["rays"].as_u64(), Some(st.rays));
    for (kind, c) in [
        ("primary", st.primary),
        ("shadow", st.shadow),
        ("reflection", st.reflection),
        ("refraction", st.refraction),
    ] {
        assert_eq!(r[kind]["rays"].as_u64(), Some(c.rays), "{kind}");
    }
    assert_eq!(r["surface_hits"].as_u64(), Some(st.surface_hits));
    assert!(std::fs::metadata(&png).unwrap().len() > 0);

    // The scene posed at another time has other triangles: an error that says so.
    let (o, _, err) = run(bin("oavm-trace")
        .arg(&file)
        .arg("--view")
        .arg(&scene_path)
        .args(["--shade", "--time", "1.5", "-o"])
        .arg(dir.path().join("t.png")));
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("packed from") && err.contains("--time"),
        "{err}"
    );
    // --depth needs --shade; --time needs --view.
    for args in [&["--depth", "2"][..], &["--time", "1"][..]] {
        let (o, _, err) = run(bin("oavm-trace").arg(&file).args(args));
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    }
}

#[test]
fn a_shot_takes_the_view_scene_or_frames_the_model() {
    let bounds = Bounds {
        min: [-1.0; 3],
        max: [1.0; 3],
    };
    // Framing the model: the default size and light, adjusted as asked.
    let shot = Shot::new(&ShotSpec::default(), &bounds).unwrap();
    assert_eq!((shot.width, shot.height), DEFAULT_SIZE);
    assert_eq!(shot.light, default_light(&bounds));
    assert_eq!(shot.camera.eye, Camera::framing(&bounds).eye);
    let spec = ShotSpec {
        light: Some([1.0, 2.0, 3.0]),
        width: Some(64),
        fov: Some(30.0),
        eye: Some([0.0, 0.0, 9.0]),
        ..ShotSpec::default()
    };
    let shot = Shot::new(&spec, &bounds).unwrap();
    assert_eq!((shot.width, shot.height), (64, DEFAULT_SIZE.1));
    assert_eq!(shot.light, [1.0, 2.0, 3.0]);
    assert_eq!(
        (shot.camera.fov_y, shot.camera.eye),
        (30.0, [0.0, 0.0, 9.0])
    );
    for bad in [
        ShotSpec {
            fov: Some(180.0),
            ..ShotSpec::default()
        },
        ShotSpec {
            eye: Some([0.0; 3]),
            target: Some([0.0; 3]),
            ..ShotSpec::default()
        },
    ] {
        let e = Shot::new(&bad, &bounds).unwrap_err().to_string();
        assert!(e.contains("--fov") && e.contains("--eye"), "{e}");
    }
    // A view scene: its camera, first light and resolution; the light and size overridable.
    let s = aff(MIRROR);
    let view = ShotSpec {
        view: Some("mirror.aff".into()),
        ..ShotSpec::default()
    };
    let shot = Shot::with_view(&view, Some(&s), &bounds).unwrap();
    assert_eq!((shot.width, shot.height), (160, 120));
    assert_eq!(shot.light, [0.0, 0.0, 1.0]);
    assert_eq!(shot.camera.eye, view_camera(&s).eye);
    let path = ShotSpec {
        camera_path: true,
        ..view.clone()
    };
    let e = Shot::with_view(&path, Some(&s), &bounds).unwrap_err();
    assert!(e.to_string().contains("no camera path"), "{e}");

    // Shaded: the scene's look, its triangles matched to the file's; a light given replaces
    // the scene's lights by one white light.
    let scene = build_scene(&s.mesh, &BuildOptions::default());
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("mirror.aff");
    std::fs::write(&file, MIRROR).unwrap();
    let lit = ShotSpec {
        view: Some(file),
        light: Some([0.0, 1.0, 0.0]),
        ..ShotSpec::default()
    };
    let shaded = ShadedShot::new(&scene, &lit, Some(1), Order::None).unwrap();
    assert_eq!(shaded.options.max_depth, 1);
    assert_eq!(shaded.look.materials, Look::from_aff(&s).materials);
    assert_eq!(
        shaded.look.lights,
        vec![PointLight {
            position: [0.0, 1.0, 0.0],
            colour: [1.0; 3]
        }]
    );
    let (_, st) = shaded.render(&scene).unwrap();
    assert_eq!((st.width, st.height), (160, 120));
}

// ---------------------------------------------------------------------------------------------
// Waves

/// The counts a render must give the same whichever way it traces.
fn counts(s: &ShadedStats) -> [u64; 12] {
    [
        s.rays,
        s.primary.rays,
        s.shadow.rays,
        s.reflection.rays,
        s.refraction.rays,
        s.hits,
        s.surface_hits,
        s.shadowed,
        s.facing_away,
        s.total_internal_reflections,
        s.depth_limited,
        s.weight_limited,
    ]
}

/// Renders `s` in waves (the default), with wave limits that send the tiles that branch most
/// ray by ray (some limit must split the tiles), and all ray by ray (limit 0): the same bytes
/// and counts. Returns the waves' render and counts.
fn waves_match_ray_by_ray(
    s: &AffScene,
    edit: impl Fn(&mut ShadedOptions) + Copy,
) -> (Image, ShadedStats) {
    let scene = build_scene(&s.mesh, &BuildOptions::default());
    let look = Look::from_aff(s);
    let mut opts = ShadedOptions::new(160, 120, view_camera(s));
    edit(&mut opts);
    assert_eq!(opts.wave_limit, oavm::render::DEFAULT_WAVE_LIMIT);
    let with_limit = |wave_limit| shade(&scene, &ShadedOptions { wave_limit, ..opts }, &look);
    let (single, s1) = with_limit(0);
    // 10 x 8 tiles.
    assert_eq!(s1.ray_by_ray_tiles, 80);
    let (waves, sw) = with_limit(opts.wave_limit);
    assert!(sw.ray_by_ray_tiles < 80, "{sw:?}");
    assert!(waves.rgb == single.rgb, "waves and ray by ray differ");
    assert_eq!(counts(&sw), counts(&s1));
    let mut split = false;
    for limit in [1_000, 3_000, 10_000, 30_000] {
        let (mixed, sm) = with_limit(limit);
        assert!(
            mixed.rgb == single.rgb,
            "waves within {limit} and ray by ray differ"
        );
        assert_eq!(counts(&sm), counts(&s1), "waves within {limit}");
        split |= sm.ray_by_ray_tiles > 0 && sm.ray_by_ray_tiles < 80;
    }
    assert!(split, "no limit sent some tiles, but not all, ray by ray");
    (waves, sw)
}

#[test]
fn waves_render_the_kitchen_as_ray_by_ray_does() {
    let path = shared_scene("bart/kitchen/kitchen.aff");
    let s = oavm::mesh::load_aff(&path, None).unwrap_or_else(|e| panic!("{e}"));
    let (_, st) = waves_match_ray_by_ray(&s, |_| {});
    // Shadows, reflections and hits all happened, so every part of a wave was compared; the
    // default limit holds every tile.
    assert_eq!(st.ray_by_ray_tiles, 0);
    assert!(st.reflection.rays > 1000, "{st:?}");
    assert!(st.shadowed > 1000 && st.shadowed < st.shadow.rays, "{st:?}");
    assert!(st.hits > 10_000, "{st:?}");
}

#[test]
fn waves_render_glass_that_reflects_and_refracts_as_ray_by_ray_does() {
    // The slab of glass, reflective too, bounced 8 times and never cut by weight: every hit
    // on it casts two rays, so the tiles that see it branch far more than the others.
    let s = aff(&format!(
        "b 0.1 0.2 0.3\nam 1 1 1\n\
         v from 0 0 100 at 0 0 0 up 0 1 0 angle 4 hither 0.01 resolution 160 120\n\
         l 0 0 50\nl 30 10 40\n\
         f 1 0 0 1 0 0 0 1\n\
         p 4  -20 -20 -5  0 -20 -5  0 20 -5  -20 20 -5\n\
         f 0 1 0 1 0 0 0 1\n\
         p 4  0 -20 -5  20 -20 -5  20 20 -5  0 20 -5\n\
         fm 0.1 0.1 0.1  0.2 0.2 0.2  0.5 0.5 0.5  30 0.6 1.5\n\
         xs 8 8 2  0 1 0 45  0 0 0 {{\n{CUBE}}}\n"
    ));
    let (_, st) = waves_match_ray_by_ray(&s, |o| {
        o.max_depth = 8;
        o.min_weight = 0.0;
    });
    assert!(st.refraction.rays > 10_000, "{st:?}");
    assert!(st.reflection.rays > 10_000, "{st:?}");
    assert!(st.total_internal_reflections > 0, "{st:?}");
    assert!(st.shadowed > 0, "{st:?}");
    assert!(st.depth_limited > 0, "{st:?}");
}
