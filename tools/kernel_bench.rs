//! Micro-benchmark of the format 4 kernels: nanoseconds per triangle-group test and per
//! cluster-node test, SSE against AVX2 (and the scalar test lane by lane, for scale).
//!
//! Data: 256 rays, each tested against 16 groups of small random triangles (eight corners,
//! eight lanes) scattered near its path, so that about half the groups have a lane the ray is
//! inside; and against 16 nodes of eight random child boxes whose cube the ray crosses. One ray
//! against many items, as in a traversal: the per-ray branches (axes the ray does not move
//! along, odd directions) are then predicted, while early exits stay as unpredictable as they
//! are in a tracer. Everything fits in L2: this times the arithmetic, not memory.
//!
//! AVX2 is timed twice: one test per call from ordinary code (each call goes through the
//! trampoline of `Avx2::vectorize`), and with the loop itself inside `vectorize`, calling the
//! `_with` kernels, as a tracer's traversal would.
//!
//! `cargo run --release --features tools --example kernel_bench`. Numbers for us, not for the docs.

use std::hint::black_box;
use std::time::Instant;

use oavm::geom::triangle::RayShear;
use oavm::geom::{BoxRay, ClusterNodeView, Ray, TriGroupView};
use oavm::os::{Avx2, WithAvx2};
use oavm::physical::format::{ClusterNode, TriGroup};

/// Rays, and items (groups, nodes) per ray.
const RAYS: usize = 256;
const PER_RAY: usize = 16;
const N: usize = RAYS * PER_RAY;
/// Passes over all items per run, and runs: the best run counts. Short runs, many of them: on
/// a machine shared with builds, some run goes uninterrupted.
const PASSES: usize = 20;
const RUNS: usize = 100;

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    /// Uniform in `[-1, 1)`.
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 23) as f32 - 1.0
    }
}

fn view(g: &TriGroup) -> TriGroupView<'_> {
    TriGroupView {
        corner: &g.corner,
        tri: &g.tri,
        count: g.count,
    }
}

fn node_view(n: &ClusterNode) -> ClusterNodeView<'_> {
    ClusterNodeView {
        origin: &n.origin,
        exp: &n.exp,
        lo: &n.lo,
        hi: &n.hi,
        child_count: n.child_count,
    }
}

/// A random ray from near the origin, and the point at `t` in `[5, 30]` along it.
fn ray_and_points(r: &mut Rng) -> (Ray, [[f32; 3]; PER_RAY]) {
    let o = [r.unit() * 10.0, r.unit() * 10.0, r.unit() * 10.0];
    let d = [r.unit(), r.unit(), r.unit()];
    let points = std::array::from_fn(|_| {
        let t = 17.5 + r.unit() * 12.5;
        std::array::from_fn(|k| o[k] + t * d[k])
    });
    (Ray::new(o, d, 0.0, f32::INFINITY), points)
}

/// For each ray, groups of eight triangles on eight corners scattered within 0.5 of a centre
/// that is within `aim` of a point of the ray.
fn groups(r: &mut Rng, aim: f32) -> (Vec<RayShear>, Vec<TriGroup>) {
    let (mut rays, mut groups) = (Vec::new(), Vec::new());
    for _ in 0..RAYS {
        let (ray, points) = ray_and_points(r);
        rays.push(RayShear::new(&ray));
        for p in points {
            let centre: [f32; 3] = std::array::from_fn(|k| p[k] + r.unit() * aim);
            let mut g = TriGroup {
                corner: [[0.0; 8]; 3],
                tri: [[0; 8]; 3],
                count: 8,
                reserved: 0,
                prim: [0; 8],
            };
            for (row, c) in g.corner.iter_mut().zip(centre) {
                for x in row.iter_mut() {
                    *x = c + r.unit() * 0.5;
                }
            }
            for l in 0..8 {
                let a = (r.next() % 8) as u8;
                let b = (a + 1 + (r.next() % 7) as u8) % 8;
                let mut c = (r.next() % 8) as u8;
                while c == a || c == b {
                    c = (c + 1) % 8;
                }
                g.tri[0][l] = a;
                g.tri[1][l] = b;
                g.tri[2][l] = c;
                g.prim[l] = l as u32;
            }
            groups.push(g);
        }
    }
    (rays, groups)
}

/// For each ray, nodes whose 4-unit cube (a grid of step 1/64) holds a point of the ray, each
/// with eight children: random boxes of 0.6 to 2 units per axis inside the cube.
fn nodes(r: &mut Rng) -> (Vec<BoxRay>, Vec<ClusterNode>) {
    let (mut rays, mut nodes) = (Vec::new(), Vec::new());
    for _ in 0..RAYS {
        let (ray, points) = ray_and_points(r);
        rays.push(BoxRay::new(&ray));
        for p in points {
            let mut n = ClusterNode {
                origin: [0.0; 3],
                exp: [-6; 3],
                child_count: 8,
                node_base: 0,
                group_base: 0,
                inner_count: 8,
                reserved: [0; 7],
                lo: [[0; 8]; 3],
                hi: [[0; 8]; 3],
            };
            for (k, &p) in p.iter().enumerate() {
                n.origin[k] = ((p - 2.0 - r.unit() * 2.0) * 64.0).round() / 64.0;
                for i in 0..8 {
                    let half = 20.0 + (r.unit() + 1.0) * 22.0;
                    let centre = 128.0 + r.unit() * (128.0 - half);
                    n.lo[k][i] = (centre - half).max(0.0) as u8;
                    n.hi[k][i] = (centre + half).min(255.0) as u8;
                }
            }
            nodes.push(n);
        }
    }
    (rays, nodes)
}

/// Best of `RUNS` runs of `PASSES` passes of `pass` (which tests all `N` items): ns per item.
fn time(mut pass: impl FnMut() -> u64) -> f64 {
    let mut best = f64::INFINITY;
    let mut sink = 0;
    for _ in 0..RUNS {
        let start = Instant::now();
        for _ in 0..PASSES {
            sink += pass();
        }
        best = best.min(start.elapsed().as_secs_f64());
    }
    black_box(sink);
    best * 1e9 / (PASSES * N) as f64
}

/// What each test's answer adds to the checksum, so that no answer is optimised away.
fn fold((mask, t): (u32, [f32; 8])) -> u64 {
    mask as u64 + t[0].to_bits() as u64
}

/// The whole pass of group tests, run inside `vectorize`.
struct GroupPass<'a>(&'a [RayShear], &'a [TriGroup]);

impl WithAvx2 for GroupPass<'_> {
    type Output = u64;
    #[inline(always)]
    fn run(self, isa: Avx2) -> u64 {
        let mut sum = 0;
        for (sh, groups) in self.0.iter().zip(self.1.chunks(PER_RAY)) {
            for g in groups {
                sum += fold(sh.intersect_group_with(isa, view(g), 0.0, f32::INFINITY));
            }
        }
        sum
    }
}

struct NodePass<'a>(&'a [BoxRay], &'a [ClusterNode]);

impl WithAvx2 for NodePass<'_> {
    type Output = u64;
    #[inline(always)]
    fn run(self, isa: Avx2) -> u64 {
        let mut sum = 0;
        for (br, nodes) in self.0.iter().zip(self.1.chunks(PER_RAY)) {
            for n in nodes {
                sum += fold(br.node_hits_with(isa, node_view(n), 0.0, f32::INFINITY));
            }
        }
        sum
    }
}

/// `test` on every (ray, item) pair, summed with [`fold`].
fn each<R, T>(rays: &[R], items: &[T], test: impl Fn(&R, &T) -> (u32, [f32; 8])) -> u64 {
    let mut sum = 0;
    for (ray, items) in rays.iter().zip(items.chunks(PER_RAY)) {
        for item in items {
            sum += fold(test(ray, black_box(item)));
        }
    }
    sum
}

fn main() {
    let avx2 = Avx2::detect();
    let mut r = Rng(0x6b65_726e_656c);
    println!(
        "kernel_bench: {RAYS} rays x {PER_RAY} items, best of {RUNS} runs of {PASSES} passes; \
         ns per test"
    );

    let (rays, gs) = groups(&mut r, 0.4);
    let per = |test: &dyn Fn(&RayShear, &TriGroup) -> u32| -> usize {
        let mut n = 0;
        for (sh, groups) in rays.iter().zip(gs.chunks(PER_RAY)) {
            n += groups.iter().map(|g| test(sh, g) as usize).sum::<usize>();
        }
        n
    };
    let inside = per(&|sh, g| {
        (sh.intersect_group(view(g), f32::NEG_INFINITY, f32::INFINITY)
            .0
            != 0) as u32
    });
    let hit = per(&|sh, g| {
        sh.intersect_group(view(g), 0.0, f32::INFINITY)
            .0
            .count_ones()
    });
    println!(
        "\ngroup test (8 lanes): {:.0} % of groups with a lane inside, {:.2} lanes hit per group",
        100.0 * inside as f64 / N as f64,
        hit as f64 / N as f64
    );
    let inf = f32::INFINITY;
    let scalar = time(|| {
        each(&rays, &gs, |sh, g| {
            sh.intersect_group_scalar(view(g), 0.0, inf)
        })
    });
    let sse = time(|| each(&rays, &gs, |sh, g| sh.intersect_group(view(g), 0.0, inf)));
    println!("  scalar, lane by lane     {scalar:6.2}");
    println!("  SSE                      {sse:6.2}");
    if let Some(isa) = avx2 {
        let call = time(|| {
            each(&rays, &gs, |sh, g| {
                sh.intersect_group_avx2(isa, view(g), 0.0, inf)
            })
        });
        let inlined = time(|| isa.vectorize(GroupPass(black_box(&rays), black_box(&gs))));
        println!("  AVX2, a call per test    {call:6.2}");
        println!("  AVX2, loop in vectorize  {inlined:6.2}");
    } else {
        println!("  AVX2: not on this CPU");
    }

    let (rays, ns) = nodes(&mut r);
    let mut hit = 0;
    for (br, nodes) in rays.iter().zip(ns.chunks(PER_RAY)) {
        for n in nodes {
            hit += br.node_hits(node_view(n), 0.0, inf).0.count_ones();
        }
    }
    println!(
        "\nnode test (8 children): {:.2} children hit per node",
        hit as f64 / N as f64
    );
    let sse = time(|| each(&rays, &ns, |br, n| br.node_hits(node_view(n), 0.0, inf)));
    println!("  SSE                      {sse:6.2}");
    if let Some(isa) = avx2 {
        let call = time(|| {
            each(&rays, &ns, |br, n| {
                br.node_hits_avx2(isa, node_view(n), 0.0, inf)
            })
        });
        let inlined = time(|| isa.vectorize(NodePass(black_box(&rays), black_box(&ns))));
        println!("  AVX2, a call per test    {call:6.2}");
        println!("  AVX2, loop in vectorize  {inlined:6.2}");
    }
}
