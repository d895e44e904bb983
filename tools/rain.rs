//! Writes the frames of "Rain", the OAVM paper's dynamic scene (Yuan et al. 2017: 15 million
//! small falling balls), for the update benchmarks: one binary little-endian PLY per frame and an
//! AFF view file to render them with.
//!
//!     cargo run --release --features tools --example rain -- --balls N --seed S --frames A..B --out DIR
//!         [--fps 25] [--shape octahedron|icosahedron] [--radius 0.1] [--json]
//!
//! writes `DIR/rain.aff` and `DIR/rain_AAAAA.ply` .. `DIR/rain_{B-1}.ply` (frame numbers padded
//! to five digits; `--frames A..=B` includes `B`, `--frames A` is one frame), then
//! `oavm-pack DIR/rain_00000.ply r.oavm && oavm-trace r.oavm --view DIR/rain.aff` renders a
//! frame. It prints, per frame and in all, the triangles, bytes and seconds (`--json`: one
//! object).
//!
//! # The scene
//!
//! The box is `x, z` in `[-50, 50]`, `y` in `[0, 100]` ([`BOX_MIN`], [`BOX_MAX`]), the ground
//! its bottom face. Every frame's triangles span exactly this box: the ground quad spans `x`,
//! `z` and `y = 0`, a marker triangle (edge 0.1) has a corner at the box's top corner
//! `(50, 100, 50)`, and every ball stays at least [`MARGIN`] inside the box at every time. So
//! an octree root cube fitted to the mesh bounds is the same in every frame, and contains every
//! frame.
//!
//! Triangles (primitive ids), the same in every frame for a given `N` and shape (`T` triangles
//! and `V` vertices a ball: the octahedron 8 and 6, the icosahedron 20 and 12):
//!
//! - 0, 1: the ground quad (facing up);
//! - `2 + i*T .. 2 + (i+1)*T`: ball `i`, its faces in the fixed order of [`Shape::faces`]
//!   (outward by the right-hand rule);
//! - `2 + N*T`: the marker at the box's top corner.
//!
//! Vertices: 0..4 the ground, 4..7 the marker, `7 + i*V .. 7 + (i+1)*V` ball `i` (in the order
//! of [`Shape::vertices`]). The faces are `list uchar uint`; `N` is refused unless the
//! `2 + N*T + 1` triangles are fewer than `0xFFFFFFFF`, as `oavm::mesh` requires of `u32`
//! primitive ids ([`max_balls`]: 536,870,911 octahedra, 214,748,364 icosahedra).
//!
//! # The motion
//!
//! Ball `i`'s parameters come from a splitmix64 stream keyed by `(seed, i)` only, so they do not
//! depend on `N` (the first 10^5 balls of a 10^6 scene are the 10^5 scene's balls) nor on the
//! frame. A ball falls at its own constant (terminal) speed, uniform in 6..12 units a second,
//! from the top of its fall to the bottom and starts again at the top (rain that reaches the
//! ground is replaced by rain at the top), and sways sideways on each of `x` and `z` with its
//! own amplitude (up to [`SWAY`]), period (3.3 to 10 s) and phase. Its position at time
//! `t = frame / fps` is closed-form ([`Ball::centre`]), so any frame is written directly, and
//! with IEEE operations only (no `sin`: the sway is a piecewise-parabolic wave), so the same
//! arguments give the same bytes on any machine. The shapes are not rotated.
//!
//! At 25 frames a second a ball falls 0.24 to 0.48 units a frame (1.2 to 2.4 radii at the
//! default radius 0.1) and sways less than 0.1. The rain is sparse at 10^5 balls; from 10^6 on,
//! seen from outside the box, the balls hide most of the ground (`--radius` thins it).
//!
//! Output files are written through `oavm::output` (atomically: a failed run leaves no partial
//! frame) and streamed: ball by ball through a `BufWriter`, vertices then faces (the faces are
//! computed from the ball index), so memory does not grow with `N` (3.4 MB peak RSS at any
//! `N`). A frame of 10^6 octahedra is 176 MB written in 0.56 s, of 10^7 1.76 GB in 5.0 s (0.75
//! s of it computing, the rest the kernel writing and syncing the file; 10^6 icosahedra: 404
//! MB, 1.15 s).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Parser;
use oavm::Error;
use oavm::output::Output;
use serde::Serialize;

#[path = "../src/bin/cli/mod.rs"]
mod cli;

/// The lowest corner of the scene box: every frame's triangles span exactly
/// [`BOX_MIN`]..[`BOX_MAX`].
pub const BOX_MIN: [f64; 3] = [-50.0, 0.0, -50.0];
/// The highest corner of the scene box.
pub const BOX_MAX: [f64; 3] = [50.0, 100.0, 50.0];
/// How far every ball stays inside the box (beyond its radius and sway).
pub const MARGIN: f64 = 0.5;
/// The largest sideways sway of a ball from its fall line, on each of `x` and `z`.
pub const SWAY: f64 = 1.0;
/// The largest `--radius`.
pub const MAX_RADIUS: f64 = 5.0;
/// The edge of the marker triangle at the box's top corner.
pub const MARKER: f64 = 0.1;
/// Vertices before the first ball's: the ground's 4 and the marker's 3.
pub const FIRST_BALL_VERTEX: u64 = 7;
/// Triangles before the first ball's: the ground's 2.
pub const FIRST_BALL_TRIANGLE: u64 = 2;

#[derive(Parser, Debug)]
#[command(
    about = "Writes the frames of the Rain scene (falling balls over a ground) as binary PLY"
)]
pub struct Args {
    /// Number of balls.
    #[arg(long)]
    pub balls: u64,
    /// Seed of the balls' start positions and speeds.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Frames to write: `A..B` (A to B-1), `A..=B` (A to B) or `A` (one frame).
    #[arg(long)]
    pub frames: String,
    /// Frames a second (frame f is at time f / fps seconds).
    #[arg(long, default_value_t = 25.0, allow_negative_numbers = true)]
    pub fps: f64,
    /// The shape of every ball.
    #[arg(long, value_enum, default_value_t = Shape::Octahedron)]
    pub shape: Shape,
    /// The radius of every ball (its vertices lie on the sphere of this radius).
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true)]
    pub radius: f64,
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// The shape of a ball.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Shape {
    /// 6 vertices, 8 triangles.
    Octahedron,
    /// 12 vertices, 20 triangles.
    Icosahedron,
}

/// The golden ratio, for the icosahedron's vertices.
const PHI: f64 = 1.618_033_988_749_895;

const OCTAHEDRON_VERTICES: [[f64; 3]; 6] = [
    [1.0, 0.0, 0.0],
    [-1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, -1.0, 0.0],
    [0.0, 0.0, 1.0],
    [0.0, 0.0, -1.0],
];

/// One face per octant, wound outward.
const OCTAHEDRON_FACES: [[u32; 3]; 8] = [
    [0, 2, 4],
    [1, 4, 2],
    [0, 4, 3],
    [0, 5, 2],
    [1, 3, 4],
    [1, 2, 5],
    [0, 3, 5],
    [1, 5, 3],
];

/// The icosahedron `(0, ±1, ±φ)` and its cyclic permutations; scaled to the unit sphere by
/// [`Shape::vertices`].
const ICOSAHEDRON_CORNERS: [[f64; 3]; 12] = [
    [-1.0, PHI, 0.0],
    [1.0, PHI, 0.0],
    [-1.0, -PHI, 0.0],
    [1.0, -PHI, 0.0],
    [0.0, -1.0, PHI],
    [0.0, 1.0, PHI],
    [0.0, -1.0, -PHI],
    [0.0, 1.0, -PHI],
    [PHI, 0.0, -1.0],
    [PHI, 0.0, 1.0],
    [-PHI, 0.0, -1.0],
    [-PHI, 0.0, 1.0],
];

/// Wound outward.
const ICOSAHEDRON_FACES: [[u32; 3]; 20] = [
    [0, 11, 5],
    [0, 5, 1],
    [0, 1, 7],
    [0, 7, 10],
    [0, 10, 11],
    [1, 5, 9],
    [5, 11, 4],
    [11, 10, 2],
    [10, 7, 6],
    [7, 1, 8],
    [3, 9, 4],
    [3, 4, 2],
    [3, 2, 6],
    [3, 6, 8],
    [3, 8, 9],
    [4, 9, 5],
    [2, 4, 11],
    [6, 2, 10],
    [8, 6, 7],
    [9, 8, 1],
];

impl Shape {
    /// The vertices of the shape inscribed in the unit sphere, in file order.
    pub fn vertices(self) -> Vec<[f64; 3]> {
        match self {
            Shape::Octahedron => OCTAHEDRON_VERTICES.to_vec(),
            Shape::Icosahedron => {
                let norm = (1.0 + PHI * PHI).sqrt();
                ICOSAHEDRON_CORNERS
                    .iter()
                    .map(|v| v.map(|c| c / norm))
                    .collect()
            }
        }
    }

    /// The number of [`Shape::vertices`].
    pub fn vertex_count(self) -> usize {
        match self {
            Shape::Octahedron => OCTAHEDRON_VERTICES.len(),
            Shape::Icosahedron => ICOSAHEDRON_CORNERS.len(),
        }
    }

    /// The faces, indices into [`Shape::vertices`], in file order.
    pub fn faces(self) -> &'static [[u32; 3]] {
        match self {
            Shape::Octahedron => &OCTAHEDRON_FACES,
            Shape::Icosahedron => &ICOSAHEDRON_FACES,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Shape::Octahedron => "octahedron",
            Shape::Icosahedron => "icosahedron",
        }
    }
}

/// The validated arguments.
#[derive(Clone, Debug)]
pub struct Config {
    pub balls: u64,
    pub seed: u64,
    /// First frame and one past the last.
    pub frames: (u64, u64),
    pub fps: f64,
    pub shape: Shape,
    pub radius: f64,
    pub out: PathBuf,
    pub json: bool,
}

impl Config {
    /// Checks `args`: a clear error for anything out of range.
    pub fn new(args: &Args) -> Result<Config, Error> {
        let bad = |m: String| Err(Error::Invalid(m));
        let shape = args.shape;
        let max = max_balls(shape);
        if args.balls == 0 {
            return bad("--balls must be at least 1".into());
        }
        if args.balls > max {
            return bad(format!(
                "--balls {}: at most {max} balls of shape {} fit u32 primitive ids (the \
                 2 + N*{} + 1 triangles must be fewer than 0xFFFFFFFF)",
                args.balls,
                shape.name(),
                shape.faces().len()
            ));
        }
        if !(args.radius > 0.0 && args.radius <= MAX_RADIUS) {
            return bad(format!(
                "--radius {}: the radius must be above 0 and at most {MAX_RADIUS} (the box is \
                 100 units)",
                args.radius
            ));
        }
        if !(args.fps.is_finite() && args.fps > 0.0) {
            return bad(format!("--fps {}: it must be a positive number", args.fps));
        }
        Ok(Config {
            balls: args.balls,
            seed: args.seed,
            frames: parse_frames(&args.frames)?,
            fps: args.fps,
            shape,
            radius: args.radius,
            out: args.out.clone(),
            json: args.json,
        })
    }

    /// Triangles a frame: the ground's, the balls', the marker.
    pub fn triangles(&self) -> u64 {
        FIRST_BALL_TRIANGLE + self.balls * self.shape.faces().len() as u64 + 1
    }

    /// Vertices a frame.
    pub fn vertices(&self) -> u64 {
        FIRST_BALL_VERTEX + self.balls * self.shape.vertex_count() as u64
    }
}

/// The most balls of `shape` whose triangles are fewer than `0xFFFFFFFF`, the most
/// `oavm::mesh` accepts (primitive ids are `u32`, `0xFFFFFFFF` meaning none).
pub fn max_balls(shape: Shape) -> u64 {
    let most_triangles = u32::MAX as u64 - 1;
    (most_triangles - FIRST_BALL_TRIANGLE - 1) / shape.faces().len() as u64
}

/// `A..B`, `A..=B` or `A`, as the first frame and one past the last.
pub fn parse_frames(text: &str) -> Result<(u64, u64), Error> {
    let bad = |why: &str| {
        Error::Invalid(format!(
            "--frames {text:?}: {why} (give A..B for frames A to B-1, A..=B, or one frame A)"
        ))
    };
    let number = |s: &str| -> Result<u64, Error> {
        s.trim()
            .parse::<u64>()
            .map_err(|e| bad(&format!("{s:?} is not a frame number: {e}")))
    };
    let (a, b) = if let Some((a, b)) = text.split_once("..=") {
        let b = number(b)?;
        (
            number(a)?,
            b.checked_add(1).ok_or_else(|| bad("too large"))?,
        )
    } else if let Some((a, b)) = text.split_once("..") {
        (number(a)?, number(b)?)
    } else {
        let a = number(text)?;
        (a, a.checked_add(1).ok_or_else(|| bad("too large"))?)
    };
    if a >= b {
        return Err(bad("the range is empty"));
    }
    Ok((a, b))
}

/// The splitmix64 finaliser (Steele, Lea and Flood 2014).
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A splitmix64 stream.
struct SplitMix(u64);

impl SplitMix {
    const GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

    /// The stream of ball `i` of the scene seeded `seed`.
    fn ball(seed: u64, i: u64) -> SplitMix {
        SplitMix(mix64(seed ^ 0x5241_494E) ^ mix64(i.wrapping_mul(Self::GAMMA) ^ 0xBA11))
    }

    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(Self::GAMMA);
        mix64(self.0)
    }

    /// Uniform in `[0, 1)`, 53 bits.
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in `[lo, hi)`.
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
}

/// A period-1 wave in `[-1, 1]` shaped like a sine (two parabolic arcs, continuous with its
/// slope), from IEEE operations only.
fn wave(phase: f64) -> f64 {
    let u = phase.rem_euclid(1.0);
    if u < 0.5 {
        16.0 * u * (0.5 - u)
    } else {
        -16.0 * (u - 0.5) * (1.0 - u)
    }
}

/// One ball's motion, from its `(seed, index)` alone.
#[derive(Clone, Copy, Debug)]
pub struct Ball {
    /// The fall line (`x`, `z` of the centre without sway).
    x: f64,
    z: f64,
    /// How far below the top of its fall the ball is at time 0, as a fraction of the fall.
    start: f64,
    /// Fall speed, units a second.
    speed: f64,
    /// Sway amplitude, frequency (cycles a second) and phase (cycles), on `x` and `z`.
    sway: [[f64; 3]; 2],
}

impl Ball {
    pub fn new(seed: u64, i: u64, radius: f64) -> Ball {
        let mut r = SplitMix::ball(seed, i);
        let inset = radius + MARGIN + SWAY;
        let x = r.range(BOX_MIN[0] + inset, BOX_MAX[0] - inset);
        let z = r.range(BOX_MIN[2] + inset, BOX_MAX[2] - inset);
        let start = r.unit();
        let speed = r.range(6.0, 12.0);
        let sway = std::array::from_fn(|_| [r.range(0.0, SWAY), r.range(0.1, 0.3), r.unit()]);
        Ball {
            x,
            z,
            start,
            speed,
            sway,
        }
    }

    /// The centre at time `t`: falling from `top` to `bottom` (the ball's lowest point
    /// [`MARGIN`] above the ground, its highest [`MARGIN`] below the box's top), back to
    /// `top` when it reaches `bottom`.
    pub fn centre(&self, t: f64, radius: f64) -> [f64; 3] {
        let top = BOX_MAX[1] - MARGIN - radius;
        let bottom = BOX_MIN[1] + MARGIN + radius;
        let fall = top - bottom;
        let fallen = (self.start * fall + self.speed * t).rem_euclid(fall);
        let sway = |k: usize| {
            let [a, f, p] = self.sway[k];
            a * wave(f * t + p)
        };
        [
            self.x + sway(0),
            (top - fallen).max(bottom),
            self.z + sway(1),
        ]
    }
}

/// The ground quad's corners (facing up) and the marker's (at the top corner).
fn fixed_vertices() -> [[f64; 3]; 7] {
    let (lo, hi) = (BOX_MIN, BOX_MAX);
    [
        [lo[0], lo[1], lo[2]],
        [hi[0], lo[1], lo[2]],
        [hi[0], lo[1], hi[2]],
        [lo[0], lo[1], hi[2]],
        [hi[0], hi[1], hi[2]],
        [hi[0] - MARKER, hi[1], hi[2]],
        [hi[0], hi[1], hi[2] - MARKER],
    ]
}

const GROUND_FACES: [[u32; 3]; 2] = [[0, 3, 2], [0, 2, 1]];
/// Facing up: `(v6 - v4) x (v5 - v4)` is `+y`.
const MARKER_FACE: [u32; 3] = [4, 6, 5];

fn face_bytes(f: [u32; 3], base: u32) -> [u8; 13] {
    let mut b = [3u8; 13];
    for (k, &i) in f.iter().enumerate() {
        b[1 + 4 * k..5 + 4 * k].copy_from_slice(&(base + i).to_le_bytes());
    }
    b
}

fn point_bytes(p: [f64; 3]) -> [u8; 12] {
    let mut b = [0u8; 12];
    for k in 0..3 {
        b[4 * k..4 * k + 4].copy_from_slice(&(p[k] as f32).to_le_bytes());
    }
    b
}

/// The frame's file name.
pub fn frame_name(frame: u64) -> String {
    format!("rain_{frame:05}.ply")
}

/// Writes frame `frame` of the scene as a binary PLY to `w`; returns the bytes written.
pub fn write_frame(w: &mut impl Write, c: &Config, frame: u64) -> std::io::Result<u64> {
    let t = frame as f64 / c.fps;
    let unit = c.shape.vertices();
    let faces = c.shape.faces();
    let header = format!(
        "ply\nformat binary_little_endian 1.0\n\
         comment Rain (tools/rain.rs): balls {} shape {} radius {} seed {} frame {} fps {} \
         time {}\n\
         comment box {:?} {:?}; triangles 0-1 ground, 2+i*{} ball i, {} marker at the top corner\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        c.balls,
        c.shape.name(),
        c.radius,
        c.seed,
        frame,
        c.fps,
        t,
        BOX_MIN,
        BOX_MAX,
        faces.len(),
        c.triangles() - 1,
        c.vertices(),
        c.triangles()
    );
    w.write_all(header.as_bytes())?;
    for p in fixed_vertices() {
        w.write_all(&point_bytes(p))?;
    }
    let mut buf = Vec::with_capacity(unit.len() * 12);
    for i in 0..c.balls {
        let centre = Ball::new(c.seed, i, c.radius).centre(t, c.radius);
        buf.clear();
        for v in &unit {
            buf.extend_from_slice(&point_bytes(std::array::from_fn(|k| {
                centre[k] + c.radius * v[k]
            })));
        }
        w.write_all(&buf)?;
    }
    for f in GROUND_FACES {
        w.write_all(&face_bytes(f, 0))?;
    }
    let mut buf = Vec::with_capacity(faces.len() * 13);
    for i in 0..c.balls {
        // Fits: Config::new bounds the vertices below the triangles below u32::MAX.
        let base = (FIRST_BALL_VERTEX + i * unit.len() as u64) as u32;
        buf.clear();
        for &f in faces {
            buf.extend_from_slice(&face_bytes(f, base));
        }
        w.write_all(&buf)?;
    }
    w.write_all(&face_bytes(MARKER_FACE, 0))?;
    Ok(header.len() as u64 + 12 * c.vertices() + 13 * c.triangles())
}

/// The view file: a camera outside the box looking at it, a light above, a background, and
/// the ground quad (an AFF scene must hold a triangle).
pub fn view_aff(c: &Config) -> String {
    let [a, b, d, e, ..] = fixed_vertices();
    let p = |v: [f64; 3]| format!("{} {} {}", v[0], v[1], v[2]);
    format!(
        "# Rain (tools/rain.rs): the view of its frames; the rain itself is in rain_*.ply\n\
         # ({} balls ({}, radius {}), seed {}, in the box {:?}..{:?}).\n\
         v\nfrom 0 70 230\nat 0 46 0\nup 0 1 0\nangle 40\nhither 1\nresolution 1024 768\n\
         b 0.55 0.62 0.7\n\
         l 40 260 110\n\
         f 0.5 0.45 0.4 1 0 0 0 1\n\
         p 4 {} {} {} {}\n",
        c.balls,
        c.shape.name(),
        c.radius,
        c.seed,
        BOX_MIN,
        BOX_MAX,
        p(a),
        p(e),
        p(d),
        p(b),
    )
}

/// One frame written.
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    pub frame: u64,
    pub path: PathBuf,
    pub bytes: u64,
    pub seconds: f64,
}

/// What a run wrote.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub balls: u64,
    pub shape: Shape,
    pub radius: f64,
    pub seed: u64,
    pub fps: f64,
    pub box_min: [f64; 3],
    pub box_max: [f64; 3],
    pub triangles_per_frame: u64,
    pub vertices_per_frame: u64,
    pub view: PathBuf,
    pub frames: Vec<FrameReport>,
    pub bytes: u64,
    pub seconds: f64,
}

/// Writes the view file and the frames; `each` is told of every frame written.
pub fn write_all(c: &Config, mut each: impl FnMut(&FrameReport)) -> Result<Report, Error> {
    let started = Instant::now();
    std::fs::create_dir_all(&c.out).map_err(|e| Error::Output {
        path: c.out.clone(),
        what: format!("cannot create the output directory: {e}"),
    })?;
    let view = c.out.join("rain.aff");
    oavm::output::write_file(&view, view_aff(c).as_bytes(), &[])?;
    let mut frames = Vec::new();
    for frame in c.frames.0..c.frames.1 {
        let t0 = Instant::now();
        let path = c.out.join(frame_name(frame));
        let bytes = write_one(c, frame, &path)?;
        let r = FrameReport {
            frame,
            path,
            bytes,
            seconds: t0.elapsed().as_secs_f64(),
        };
        each(&r);
        frames.push(r);
    }
    Ok(Report {
        balls: c.balls,
        shape: c.shape,
        radius: c.radius,
        seed: c.seed,
        fps: c.fps,
        box_min: BOX_MIN,
        box_max: BOX_MAX,
        triangles_per_frame: c.triangles(),
        vertices_per_frame: c.vertices(),
        view,
        bytes: frames.iter().map(|f| f.bytes).sum(),
        frames,
        seconds: started.elapsed().as_secs_f64(),
    })
}

fn write_one(c: &Config, frame: u64, path: &Path) -> Result<u64, Error> {
    let mut out = Output::create(path, &[])?;
    let failed = |e: std::io::Error| Error::Output {
        path: path.to_owned(),
        what: format!("cannot write it: {e}"),
    };
    let mut w = std::io::BufWriter::with_capacity(1 << 20, out.file());
    let bytes = write_frame(&mut w, c, frame).map_err(failed)?;
    w.flush().map_err(failed)?;
    drop(w);
    out.commit()?;
    Ok(bytes)
}

/// Parses, validates, writes and reports.
pub fn run(args: &Args) -> Result<(), Error> {
    let c = Config::new(args)?;
    let report = write_all(&c, |f| {
        if !c.json {
            println!(
                "{}: frame {} ({:.3} s), {} triangles, {} bytes, {:.2} s",
                f.path.display(),
                f.frame,
                f.frame as f64 / c.fps,
                c.triangles(),
                f.bytes,
                f.seconds
            );
        }
    })?;
    if c.json {
        cli::print_json(&report)
    } else {
        cli::print_text(&format!(
            "wrote {} frames of {} balls ({}, radius {}, seed {}): {} triangles a frame, {} bytes, \
             {:.2} s ({:.2} s a frame); view: {}\n",
            report.frames.len(),
            c.balls,
            c.shape.name(),
            c.radius,
            c.seed,
            report.triangles_per_frame,
            report.bytes,
            report.seconds,
            report.seconds / report.frames.len() as f64,
            report.view.display()
        ))
    }
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    cli::main_with("rain", || run(&args))
}
