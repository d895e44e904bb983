//! The cluster builder against its checker, brute force and awkward inputs:
//!
//! - the bunny cut into clusters by a grid of boxes: every triangle in exactly one lane, bit for
//!   bit and in its corner order, the checker satisfied, the bytes the same on a rebuild;
//! - reachability: for random rays, every triangle the f64 reference hits inside the clip box is
//!   in a group a box-culled traversal reaches;
//! - one triangle, ten thousand identical ones, fans, slivers, a triangle far larger than the
//!   clip box, triangles that miss it, signed zeros, a depth cap the SAH tree exceeds;
//! - the checker refuses corrupted boxes, indices, counts and slots.
//!
//! The figures that choose the cluster size are printed by `tools/cluster_stats.rs`.

use std::collections::HashMap;
use std::path::PathBuf;

use bytemuck::Zeroable;

use super::*;
use crate::geom::Ray;
use crate::geom::reference::meet;
use crate::geom::tribox::corner_bounds;
use crate::physical::{check_cluster, check_with_depth};

/// A small deterministic generator (xorshift64).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    /// Uniform in `[lo, hi)`.
    fn f(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (self.next() >> 11) as f64 / (1u64 << 53) as f64 * (hi - lo)
    }
    fn point(&mut self, lo: [f64; 3], hi: [f64; 3]) -> [f32; 3] {
        std::array::from_fn(|k| self.f(lo[k], hi[k]) as f32)
    }
}

type Clip = ([f64; 3], [f64; 3]);

fn scene(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/scenes")
        .join(rel)
}

fn load_tris(rel: &str) -> Vec<ClusterTri> {
    let path = scene(rel);
    let mesh = crate::mesh::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (0..mesh.triangles.len())
        .map(|i| ClusterTri {
            v: mesh.triangle(i),
            prim: i as u32,
        })
        .filter(|t| !crate::geom::triangle::is_degenerate(&t.v))
        .collect()
}

fn bounds_of(tris: &[ClusterTri]) -> Clip {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in tris.iter().flat_map(|t| &t.v) {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    (lo, hi)
}

/// The bunny cut by an `n`³ grid of boxes over its bounds, each widened by 2 % of its edge:
/// per box, the clip box and the triangles whose bounding boxes overlap it.
fn grid_clusters(tris: &[ClusterTri], n: usize) -> Vec<(Clip, Vec<ClusterTri>)> {
    let (lo, hi) = bounds_of(tris);
    let mut out = Vec::new();
    for c in 0..n * n * n {
        let cell = [c % n, c / n % n, c / (n * n)];
        let clip: Clip = {
            let e: [f64; 3] = std::array::from_fn(|k| (hi[k] - lo[k]) / n as f64);
            (
                std::array::from_fn(|k| lo[k] + cell[k] as f64 * e[k] - 0.02 * e[k]),
                std::array::from_fn(|k| lo[k] + (cell[k] + 1) as f64 * e[k] + 0.02 * e[k]),
            )
        };
        let inside: Vec<ClusterTri> = tris
            .iter()
            .filter(|t| {
                let (a, b) = corner_bounds(&t.v);
                (0..3).all(|k| a[k] as f64 <= clip.1[k] && b[k] as f64 >= clip.0[k])
            })
            .copied()
            .collect();
        if !inside.is_empty() {
            out.push((clip, inside));
        }
    }
    out
}

/// Everything [`build_cluster`] promises, for `tris` in `clip`: the checker passes, the shape is
/// what was built, every triangle is in exactly one lane bit for bit (corner order kept), and a
/// rebuild (at other bases) gives the same bytes up to the bases. Returns the build.
fn build_and_check(tris: &[ClusterTri], clip: Clip) -> ClusterBuild {
    build_and_check_window(tris, clip, WINDOW)
}

/// [`build_and_check`] with windows of `window` triangles.
fn build_and_check_window(tris: &[ClusterTri], clip: Clip, window: usize) -> ClusterBuild {
    let b = ClusterBuilder::with_window(window)
        .build(tris, clip, 0, 0)
        .unwrap();
    check_build(tris, clip, &b, window);
    // The same at other bases, in a block that holds something before it.
    let (nb, gb) = (3u32, 5u32);
    let mut nodes = vec![ClusterNode::zeroed(); nb as usize];
    let mut groups = vec![TriGroup::zeroed(); gb as usize];
    ClusterBuilder::with_window(window)
        .build_into(tris, clip, &mut nodes, &mut groups)
        .unwrap();
    let shape = check_cluster(&nodes, &groups, nb, clip).unwrap();
    // The root at `nb`, the nodes below it right after (the builder's layout).
    assert_eq!(shape.below, nb + 1..nb + b.nodes.len() as u32);
    assert_eq!(shape.groups, gb..gb + b.groups.len() as u32);
    assert_eq!(&groups[gb as usize..], &b.groups[..], "groups differ");
    for (x, y) in nodes[nb as usize..].iter().zip(&b.nodes) {
        let mut x = *x;
        if x.inner_count > 0 {
            x.node_base -= nb;
        }
        if x.child_count > x.inner_count {
            x.group_base -= gb;
        }
        assert_eq!(&x, y, "nodes differ but for the bases");
    }
    b
}

fn check_build(tris: &[ClusterTri], clip: Clip, b: &ClusterBuild, window: usize) {
    let shape = check_cluster(&b.nodes, &b.groups, 0, clip).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(shape.below, 1..b.nodes.len() as u32);
    assert_eq!(shape.groups, 0..b.groups.len() as u32);
    assert_eq!(shape.triangles, tris.len() as u64);
    assert!(shape.depth as usize <= MAX_CLUSTER_DEPTH);
    // Every input triangle in exactly one lane: match lanes to inputs by (prim, corner bits).
    type Key = (u32, [[u32; 3]; 3]);
    let key = |prim: u32, v: &[[f32; 3]; 3]| -> Key { (prim, v.map(|p| p.map(f32::to_bits))) };
    let mut want: HashMap<Key, u32> = HashMap::new();
    for t in tris {
        *want.entry(key(t.prim, &t.v)).or_default() += 1;
    }
    for g in &b.groups {
        assert!((1..=8).contains(&g.count));
        let mut corners: Vec<[u32; 3]> = Vec::new();
        for l in 0..g.count as usize {
            let v = g.triangle(l);
            for p in &v {
                if !corners.contains(&corner_key(p)) {
                    corners.push(corner_key(p));
                }
            }
            let k = key(g.prim[l], &v);
            let left = want
                .get_mut(&k)
                .filter(|n| **n > 0)
                .unwrap_or_else(|| panic!("lane {l} holds a triangle not in the input: {k:?}"));
            *left -= 1;
        }
        assert!(corners.len() <= 8);
        // Corner slots used are 0..m, in order of first use, the rest zero.
        let m = corners.len();
        for j in m..8 {
            assert_eq!(
                (g.corner[0][j], g.corner[1][j], g.corner[2][j]),
                (0.0, 0.0, 0.0)
            );
        }
    }
    assert!(want.values().all(|&n| n == 0), "triangles missing");
    // Deterministic.
    let again = ClusterBuilder::with_window(window)
        .build(tris, clip, 0, 0)
        .unwrap();
    assert_eq!(
        bytemuck::cast_slice::<_, u8>(&again.nodes),
        bytemuck::cast_slice::<_, u8>(&b.nodes)
    );
    assert_eq!(
        bytemuck::cast_slice::<_, u8>(&again.groups),
        bytemuck::cast_slice::<_, u8>(&b.groups)
    );
}

#[test]
fn bunny_grid_clusters() {
    let tris = load_tris("bunny/bun_zipper.ply");
    let clusters = grid_clusters(&tris, 3);
    assert!(clusters.len() >= 10, "{} clusters", clusters.len());
    let mut lanes = 0;
    let mut groups = 0;
    let mut some_clipped = false;
    for (clip, t) in &clusters {
        let b = build_and_check(t, *clip);
        lanes += t.len();
        groups += b.groups.len();
        // Every window size builds a valid cluster (1: no greedy grouping; 64: the largest).
        for w in [1, 32, 64] {
            build_and_check_window(t, *clip, w);
        }
        some_clipped |= t.iter().any(|t| {
            let (a, c) = corner_bounds(&t.v);
            (0..3).any(|k| (a[k] as f64) < clip.0[k] || c[k] as f64 > clip.1[k])
        });
    }
    assert!(
        some_clipped,
        "no triangle crosses a clip box: the clipping is untested"
    );
    let fill = lanes as f64 / groups as f64;
    assert!(fill > 4.0, "{fill} lanes per group");
}

/// Every slot (and the root) whose box a ray meets, with `tol` of slack: the groups reached.
fn reached_groups(b: &ClusterBuild, ray: &Ray, tol: f64) -> Vec<u32> {
    let o = ray.origin.map(f64::from);
    let d = ray.dir.map(f64::from);
    let meets = |(lo, hi): ([f32; 3], [f32; 3])| {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for k in 0..3 {
            let (l, h) = (lo[k] as f64 - tol, hi[k] as f64 + tol);
            if d[k] == 0.0 {
                if o[k] < l || o[k] > h {
                    return false;
                }
            } else {
                let (a, c) = ((l - o[k]) / d[k], (h - o[k]) / d[k]);
                t0 = t0.max(a.min(c));
                t1 = t1.min(a.max(c));
            }
        }
        t0 <= t1
    };
    let mut out = Vec::new();
    let mut stack = vec![0u32];
    while let Some(n) = stack.pop() {
        let node = &b.nodes[n as usize];
        for i in 0..node.child_count as usize {
            if !meets(node.child_box(i)) {
                continue;
            }
            if i < node.inner_count as usize {
                stack.push(node.node_base + i as u32);
            } else {
                out.push(node.group_base + (i - node.inner_count as usize) as u32);
            }
        }
    }
    out
}

/// For `rays` random rays through `clip`, every triangle the f64 reference hits (at `t >= 0`)
/// inside `clip` is in a group that box culling reaches. Returns the fraction of the cluster's
/// triangles the traversal reached on average (culling works if well below 1).
fn check_reachability(tris: &[ClusterTri], clip: Clip, rays: usize, seed: u64) -> f64 {
    check_reachability_window(tris, clip, rays, seed, WINDOW)
}

/// [`check_reachability`] with windows of `window` triangles.
fn check_reachability_window(
    tris: &[ClusterTri],
    clip: Clip,
    rays: usize,
    seed: u64,
    window: usize,
) -> f64 {
    let b = build_and_check_window(tris, clip, window);
    let (lo, hi) = clip;
    let ext: [f64; 3] = std::array::from_fn(|k| hi[k] - lo[k]);
    let scale = (0..3).fold(0f64, |m, k| m.max(lo[k].abs()).max(hi[k].abs()));
    let tol = 1e-9 * scale.max(1e-30) + 1e-9 * ext.iter().fold(0f64, |a, &b| a.max(b));
    let mut rng = Rng(seed);
    let (mut reached_sum, mut hits) = (0usize, 0usize);
    for r in 0..rays {
        let o = rng.point(
            std::array::from_fn(|k| lo[k] - ext[k]),
            std::array::from_fn(|k| hi[k] + ext[k]),
        );
        // Aim at a point of the clip box or (every other ray) of a triangle, and one ray in 8
        // along an axis.
        let target = if r % 2 == 0 {
            rng.point(lo, hi)
        } else {
            let t = &tris[rng.next() as usize % tris.len()].v;
            let (a, b) = (rng.f(0.0, 1.0), rng.f(0.0, 1.0));
            let (a, b) = if a + b > 1.0 {
                (1.0 - a, 1.0 - b)
            } else {
                (a, b)
            };
            std::array::from_fn(|k| {
                let p = t.map(|p| p[k] as f64);
                (p[0] + a * (p[1] - p[0]) + b * (p[2] - p[0])) as f32
            })
        };
        let mut dir: [f32; 3] = std::array::from_fn(|k| target[k] - o[k]);
        if r % 8 == 0 {
            let keep = (r / 8) % 3;
            for (k, d) in dir.iter_mut().enumerate() {
                if k != keep {
                    *d = 0.0;
                }
            }
        }
        if dir == [0.0; 3] {
            continue;
        }
        let ray = Ray::new(o, dir, 0.0, f32::INFINITY);
        let reached = reached_groups(&b, &ray, tol);
        reached_sum += reached
            .iter()
            .map(|&g| b.groups[g as usize].count as usize)
            .sum::<usize>();
        let prims: std::collections::HashSet<u32> = reached
            .iter()
            .flat_map(|&g| {
                let g = &b.groups[g as usize];
                g.prim[..g.count as usize].to_vec()
            })
            .collect();
        for t in tris {
            let Some(m) = meet(&t.v, &ray) else { continue };
            if m.u < 0.0 || m.v < 0.0 || m.u + m.v > 1.0 || m.t < 0.0 {
                continue;
            }
            let p = ray.at(m.t);
            if !(0..3).all(|k| lo[k] <= p[k] && p[k] <= hi[k]) {
                continue;
            }
            hits += 1;
            assert!(
                prims.contains(&t.prim),
                "ray {r} {ray:?} hits primitive {} at {p:?} inside the clip box, but no \
                 traversal reaches it",
                t.prim
            );
        }
    }
    assert!(hits > rays / 20, "only {hits} hits: the test tests little");
    reached_sum as f64 / (rays * tris.len()) as f64
}

#[test]
fn every_hit_inside_the_clip_box_is_reachable_bunny() {
    let tris = load_tris("bunny/bun_zipper.ply");
    let clusters = grid_clusters(&tris, 3);
    // The three largest clusters.
    let mut by_size: Vec<&(Clip, Vec<ClusterTri>)> = clusters.iter().collect();
    by_size.sort_by_key(|c| std::cmp::Reverse(c.1.len()));
    for (i, (clip, t)) in by_size.into_iter().take(3).enumerate() {
        let reached = check_reachability(t, *clip, 1500, 7 + i as u64);
        assert!(
            reached < 0.2,
            "traversal reaches {reached} of the triangles per ray"
        );
    }
}

/// Random triangles, many far larger than the clip box or crossing it, so that only the
/// clipped boxes (not the triangles' own) are in the tree.
#[test]
fn every_hit_inside_the_clip_box_is_reachable_big_triangles() {
    let mut rng = Rng(0x1234_5678_9abc_def1);
    let clip: Clip = ([10.0, -3.0, 100.0], [11.0, -2.5, 100.75]);
    let mut tris = Vec::new();
    for i in 0..600u32 {
        // A small triangle somewhere around the clip box, or a long one through it.
        let reach = if i % 3 == 0 { 20.0 } else { 0.3 };
        let c = rng.point(
            std::array::from_fn(|k| clip.0[k] - 0.2),
            std::array::from_fn(|k| clip.1[k] + 0.2),
        );
        let v: [[f32; 3]; 3] =
            std::array::from_fn(|_| std::array::from_fn(|k| c[k] + rng.f(-reach, reach) as f32));
        if !crate::geom::triangle::is_degenerate(&v) {
            tris.push(ClusterTri { v, prim: i });
        }
    }
    for window in [1, WINDOW, 64] {
        let reached = check_reachability_window(&tris, clip, 1500, 99, window);
        assert!(
            reached < 0.5,
            "traversal reaches {reached} of the triangles per ray"
        );
    }
}

#[test]
fn one_triangle() {
    let t = ClusterTri {
        v: [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        prim: 42,
    };
    let clip: Clip = ([-1.0; 3], [2.0; 3]);
    let b = build_and_check(&[t], clip);
    assert_eq!((b.nodes.len(), b.groups.len()), (1, 1));
    let n = &b.nodes[0];
    assert_eq!((n.child_count, n.inner_count), (1, 0));
    assert_eq!(b.groups[0].count, 1);
    assert_eq!(b.groups[0].prim[0], 42);
    assert_eq!(b.groups[0].triangle(0), t.v);
    // The box is the triangle's, exactly (its faces are on the grid).
    assert_eq!(n.child_box(0), ([0.0, 0.0, 0.0], [1.0, 1.0, 0.0]));
}

#[test]
fn ten_thousand_identical_triangles() {
    let v = [[0.5, 0.25, 3.0], [1.5, 0.25, 3.0], [0.5, 2.0, 3.5]];
    let tris: Vec<ClusterTri> = (0..10_000).map(|i| ClusterTri { v, prim: i }).collect();
    let clip: Clip = ([0.0; 3], [4.0; 3]);
    let b = build_and_check(&tris, clip);
    // Nothing separates them: split by count into full groups.
    assert_eq!(b.groups.len(), 1250);
    assert!(b.groups.iter().all(|g| g.count == 8));
    let shape = check_cluster(&b.nodes, &b.groups, 0, clip).unwrap();
    assert!(shape.depth <= 5, "depth {}", shape.depth);
}

#[test]
fn a_fan_around_one_vertex() {
    // 100 triangles around the origin: any group holds the centre and at most 7 rim corners,
    // i.e. up to 6 consecutive triangles.
    let rim = |i: u32| {
        let a = i as f64 / 100.0 * std::f64::consts::TAU;
        [
            a.cos() as f32,
            a.sin() as f32,
            0.25 * (a * 3.0).sin() as f32,
        ]
    };
    let tris: Vec<ClusterTri> = (0..100)
        .map(|i| ClusterTri {
            v: [[0.0; 3], rim(i), rim((i + 1) % 100)],
            prim: i,
        })
        .collect();
    let clip: Clip = ([-0.5, -0.5, -1.0], [1.5, 1.5, 1.0]);
    let b = build_and_check(&tris, clip);
    let fill = 100.0 / b.groups.len() as f64;
    assert!(fill >= 4.0, "{fill} lanes per group");
    // Windows of 32: the greedy grouping finds runs of 6 (a window of 25 consecutive
    // triangles gives 6 + 6 + 6 + 6 + 1), fuller than SAH splits (windows of 1).
    let fill_of = |w| 100.0 / build_and_check_window(&tris, clip, w).groups.len() as f64;
    let (sah, greedy) = (fill_of(1), fill_of(32));
    assert!(
        greedy >= 5.0 && greedy > sah,
        "{greedy} lanes per group, {sah} with SAH alone"
    );
    check_reachability(&tris, clip, 400, 5);
}

#[test]
fn thin_slivers() {
    // Needles along x, at most 1e-3 wide, stacked, crossing the clip box.
    let mut tris = Vec::new();
    for i in 0..200u32 {
        let y = i as f32 * 0.01;
        tris.push(ClusterTri {
            v: [[0.0, y, 0.0], [5.0, y, 0.0], [5.0, y + 1e-3, 1e-3]],
            prim: i,
        });
    }
    let clip: Clip = ([1.0, 0.0, -0.1], [2.0, 1.0, 0.1]);
    build_and_check(&tris, clip);
    check_reachability(&tris, clip, 400, 11);
}

#[test]
fn a_triangle_far_larger_than_the_clip_box() {
    let big = ClusterTri {
        v: [[-1e6, -1e6, 0.3], [1e6, -1e6, 0.3], [0.0, 1e6, 0.7]],
        prim: 0,
    };
    let small = ClusterTri {
        v: [[0.1, 0.1, 0.1], [0.2, 0.1, 0.1], [0.1, 0.2, 0.2]],
        prim: 1,
    };
    let clip: Clip = ([0.0; 3], [1.0; 3]);
    let b = build_and_check(&[big, small], clip);
    // Its box is its part inside the clip box (a slab across it), not its own bounds.
    let (lo, hi) = b.nodes[0].child_box(0);
    assert!(
        lo.iter().chain(&hi).all(|c| (-0.01..=1.01).contains(c)),
        "{lo:?} {hi:?}"
    );
    check_reachability(&[big, small], clip, 300, 3);
}

#[test]
fn triangles_that_miss_or_touch_the_clip_box() {
    let clip: Clip = ([0.0; 3], [1.0; 3]);
    let tris = [
        // Its bounding box overlaps the clip box, the triangle does not (it passes the corner).
        ClusterTri {
            v: [[3.5, 0.0, 0.0], [0.0, 3.5, 0.0], [0.0, 0.0, 3.5]],
            prim: 0,
        },
        // Touches the face x = 1 from outside.
        ClusterTri {
            v: [[1.0, 0.2, 0.2], [2.0, 0.2, 0.2], [2.0, 0.8, 0.5]],
            prim: 1,
        },
        // Wholly outside.
        ClusterTri {
            v: [[5.0, 5.0, 5.0], [6.0, 5.0, 5.0], [5.0, 6.0, 5.0]],
            prim: 2,
        },
        ClusterTri {
            v: [[0.1, 0.1, 0.1], [0.9, 0.1, 0.1], [0.1, 0.9, 0.9]],
            prim: 3,
        },
    ];
    assert!(triangle_box(&tris[2].v, &clip).is_none());
    let touch = triangle_box(&tris[1].v, &clip).unwrap();
    assert_eq!(touch.0[0], 1.0);
    assert_eq!(touch.1[0], 1.0);
    build_and_check(&tris, clip);
}

#[test]
fn signed_zeros_are_distinct_corners() {
    // Eight triangles that would share 3 corners if -0.0 were 0.0, and have 6.
    let tris: Vec<ClusterTri> = (0..8)
        .map(|i| {
            let z = if i % 2 == 0 { 0.0 } else { -0.0 };
            ClusterTri {
                v: [[z, 0.0, 0.0], [1.0, z, 0.0], [0.0, 1.0, z]],
                prim: i,
            }
        })
        .collect();
    let b = build_and_check(&tris, ([-1.0; 3], [2.0; 3]));
    assert_eq!(b.groups.len(), 1);
    let g = &b.groups[0];
    for l in 0..8 {
        assert_eq!(
            g.triangle(l).map(|p| p.map(f32::to_bits)),
            tris[g.prim[l] as usize].v.map(|p| p.map(f32::to_bits))
        );
    }
}

#[test]
fn far_from_the_origin_and_flat() {
    // Coordinates around 3e7 (where f32 steps are 2) and a cluster flat in z.
    let mut rng = Rng(77);
    let base = [3.0e7f64, -4.1e7, 1.5e7];
    let clip: Clip = (base, [base[0] + 4096.0, base[1] + 4096.0, base[2] + 1.0]);
    let tris: Vec<ClusterTri> = (0..500)
        .map(|i| {
            let c = rng.point(clip.0, clip.1);
            ClusterTri {
                v: [
                    [c[0], c[1], base[2] as f32],
                    [c[0] + 64.0, c[1], base[2] as f32],
                    [c[0], c[1] + 64.0, base[2] as f32],
                ],
                prim: i,
            }
        })
        .collect();
    build_and_check(&tris, clip);
    // And tiny: a cluster 1e-30 across.
    let tiny: Vec<ClusterTri> = (0..50)
        .map(|i| {
            let c = rng.point([0.0; 3], [1e-30; 3]);
            ClusterTri {
                v: [
                    c,
                    [c[0] + 1e-32, c[1], c[2]],
                    [c[0], c[1] + 1e-32, c[2] + 1e-33],
                ],
                prim: i,
            }
        })
        .filter(|t| !crate::geom::triangle::is_degenerate(&t.v))
        .collect();
    build_and_check(&tiny, ([0.0; 3], [2e-30; 3]));
}

#[test]
fn bad_inputs_are_errors() {
    let t = ClusterTri {
        v: [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        prim: 0,
    };
    let clip: Clip = ([0.0; 3], [1.0; 3]);
    assert_eq!(build_cluster(&[], clip, 0, 0), Err(ClusterError::Empty));
    let mut nan = t;
    nan.v[1][2] = f32::NAN;
    assert!(matches!(
        build_cluster(&[t, nan], clip, 0, 0),
        Err(ClusterError::NonFinite { index: 1, .. })
    ));
    assert!(matches!(
        build_cluster(&[t], ([0.0; 3], [-1.0, 1.0, 1.0]), 0, 0),
        Err(ClusterError::BadClip { .. })
    ));
    let huge = ClusterTri {
        v: [[0.0, 0.0, 0.0], [3e38, 0.0, 0.0], [0.0, 1.0, 0.0]],
        prim: 1,
    };
    assert!(matches!(
        build_cluster(&[huge], ([0.0; 3], [1e39; 3]), 0, 0),
        Err(ClusterError::Range { .. })
    ));
    assert_eq!(
        build_cluster(&[t], clip, u32::MAX, 0).map(|b| b.nodes.len()),
        Ok(1),
        "a root alone at the last index"
    );
    let many: Vec<ClusterTri> = (0..100).map(|i| ClusterTri { prim: i, ..t }).collect();
    assert_eq!(
        build_cluster(&many, clip, u32::MAX - 1, 0),
        Err(ClusterError::IndexOverflow)
    );
}

/// A tree the SAH makes deeper than the cap is rebuilt shallow (median splits, tallest child
/// opened first) and meets it; a cap no tree can meet is an error.
#[test]
fn the_depth_cap_holds() {
    // Rows of 8 triangles at x = 2^0 .. 2^63 (and again; a node's extent must stay below the
    // 2^70 that exponents up to 63 allow, spec §7.1): the SAH peels off a few rows at a time,
    // a deep, lopsided tree, where median splits make 3.
    let tris: Vec<ClusterTri> = (0..2000u32)
        .map(|i| {
            let x = 2f32.powi((i / 8) as i32 % 64);
            let y = (i % 8) as f32;
            ClusterTri {
                v: [[x, y, 0.0], [x + 1.0, y, 0.0], [x, y + 1.0, 1.0]],
                prim: i,
            }
        })
        .collect();
    let clip: Clip = ([0.0; 3], [1e37; 3]);
    let sah = build_cluster(&tris, clip, 0, 0).unwrap();
    let sah_depth = check_cluster(&sah.nodes, &sah.groups, 0, clip)
        .unwrap()
        .depth;
    assert!(
        sah_depth >= 8,
        "the SAH tree is only {sah_depth} deep: pick another input"
    );
    let cap = 4;
    let params = Params {
        max_depth: cap,
        ..Params::default()
    };
    let b = ClusterBuilder::with_params(params)
        .build(&tris, clip, 0, 0)
        .unwrap();
    let shape = check_with_depth(&b.nodes, &b.groups, 0, clip, cap).unwrap();
    assert!(shape.depth as usize <= cap);
    assert_eq!(shape.triangles, 2000);
    assert!(
        check_with_depth(&sah.nodes, &sah.groups, 0, clip, cap).is_err(),
        "the checker enforces the cap"
    );
    // A lone root holds at most 8 groups.
    let params = Params {
        max_depth: 0,
        ..Params::default()
    };
    assert_eq!(
        ClusterBuilder::with_params(params).build(&tris, clip, 0, 0),
        Err(ClusterError::TooDeep { cap: 0 })
    );
}

/// A hundred thousand triangles in one cluster (a pathological leaf): built and checked in
/// a moment, no step is quadratic.
#[test]
fn a_hundred_thousand_triangles() {
    let mut rng = Rng(0xdead_beef_1234_5678);
    let clip: Clip = ([0.0; 3], [1.0; 3]);
    let tris: Vec<ClusterTri> = (0..100_000)
        .map(|i| {
            let c = rng.point([-0.05; 3], [1.05; 3]);
            let v =
                std::array::from_fn(|_| std::array::from_fn(|k| c[k] + rng.f(-0.01, 0.01) as f32));
            ClusterTri { v, prim: i }
        })
        .filter(|t| !crate::geom::triangle::is_degenerate(&t.v))
        .collect();
    let b = build_cluster(&tris, clip, 0, 0).unwrap();
    let shape = check_cluster(&b.nodes, &b.groups, 0, clip).unwrap();
    assert_eq!(shape.triangles, tris.len() as u64);
    assert!(shape.depth <= 8, "depth {}", shape.depth);
}

/// Random bytes in a valid cluster's records: the checker answers, it never panics.
#[test]
fn the_checker_never_panics_on_bytes() {
    let (_, clip, b) = corruptible();
    let mut rng = Rng(0x0123_4567_89ab_cdef);
    let mut refused = 0;
    for round in 0..3000 {
        let (mut n, mut g) = (b.nodes.clone(), b.groups.clone());
        for _ in 0..1 + round % 4 {
            let bytes: &mut [u8] = if rng.next().is_multiple_of(2) {
                bytemuck::cast_slice_mut(&mut n)
            } else {
                bytemuck::cast_slice_mut(&mut g)
            };
            let at = rng.next() as usize % bytes.len();
            bytes[at] = rng.next() as u8;
        }
        let root = if round % 50 == 0 {
            rng.next() as u32 % 8
        } else {
            0
        };
        refused += check_cluster(&n, &g, root, clip).is_err() as u32;
    }
    assert!(refused > 1000, "only {refused} of 3000 corruptions refused");
}

/// A built cluster with enough structure to corrupt: the largest bunny grid cluster, without
/// the triangles that have nothing inside the clip box (so every box is tight to what the
/// checker requires).
fn corruptible() -> (Vec<ClusterTri>, Clip, ClusterBuild) {
    let tris = load_tris("bunny/bun_zipper.ply");
    let (clip, mut t) = grid_clusters(&tris, 4)
        .into_iter()
        .max_by_key(|c| c.1.len())
        .unwrap();
    t.retain(|t| triangle_box(&t.v, &clip).is_some());
    let b = build_cluster(&t, clip, 0, 0).unwrap();
    (t, clip, b)
}

#[test]
fn the_checker_refuses_corruption() {
    let (_, clip, b) = corruptible();
    assert!(check_cluster(&b.nodes, &b.groups, 0, clip).is_ok());
    let fails = |what: &str, f: &dyn Fn(&mut Vec<ClusterNode>, &mut Vec<TriGroup>)| {
        let (mut n, mut g) = (b.nodes.clone(), b.groups.clone());
        f(&mut n, &mut g);
        let r = check_cluster(&n, &g, 0, clip);
        assert!(r.is_err(), "{what}: the checker accepts it");
        eprintln!("{what}: {}", r.unwrap_err());
    };
    // Every face of every slot, moved inward by one step, loses something (the faces are
    // tight to within the rounding, and the clipped boxes touch them).
    let mut shrinks = 0;
    for ni in 0..b.nodes.len() {
        for i in 0..b.nodes[ni].child_count as usize {
            for k in 0..3 {
                for hi_face in [false, true] {
                    let (mut n, g) = (b.nodes.clone(), b.groups.clone());
                    let node = &mut n[ni];
                    if node.lo[k][i] == node.hi[k][i] {
                        continue;
                    }
                    if hi_face {
                        node.hi[k][i] -= 1;
                    } else {
                        node.lo[k][i] += 1;
                    }
                    assert!(
                        check_cluster(&n, &g, 0, clip).is_err(),
                        "node {ni} slot {i} axis {k} {} face moved in: accepted",
                        if hi_face { "high" } else { "low" }
                    );
                    shrinks += 1;
                }
            }
        }
    }
    assert!(shrinks > 100);
    let inner = (0..b.nodes.len())
        .find(|&i| b.nodes[i].inner_count > 0)
        .expect("a node with an inner child");
    fails("inner child past the end", &|n, _| {
        n[inner].node_base = n.len() as u32
    });
    fails("inner child before its parent", &|n, _| {
        n[inner].node_base = inner as u32
    });
    fails("inner child overflowing", &|n, _| {
        n[inner].node_base = u32::MAX
    });
    fails("a node reached twice", &|n, _| {
        // Two inner slots on one node.
        let b2 = n[inner].node_base;
        let other = (0..n.len()).find(|&i| i != inner && n[i].inner_count > 0);
        match other {
            Some(o) => n[o].node_base = b2,
            None => n[inner].node_base = b2 + 1,
        }
    });
    let leafy = (0..b.nodes.len())
        .find(|&i| b.nodes[i].child_count > b.nodes[i].inner_count)
        .unwrap();
    fails("group past the end", &|n, g| {
        n[leafy].group_base = g.len() as u32
    });
    fails("a group reached twice", &|n, _| {
        let other = (0..n.len())
            .find(|&i| i != leafy && n[i].child_count > n[i].inner_count)
            .unwrap();
        n[other].group_base = n[leafy].group_base;
    });
    fails("no children", &|n, _| n[0].child_count = 0);
    fails("nine children", &|n, _| n[0].child_count = 9);
    fails("more inner than children", &|n, _| {
        n[0].inner_count = n[0].child_count + 1
    });
    fails("exponent out of range", &|n, _| n[0].exp[1] = 101);
    fails("origin off the grid", &|n, _| {
        n[0].origin[2] += 2f32.powi(n[0].exp[2] as i32 - 1)
    });
    fails("an unused slot not zero", &|n, _| {
        let i = (0..n.len()).find(|&i| n[i].child_count < 8).unwrap();
        n[i].hi[0][7] = 1;
    });
    fails("inverted slot", &|n, _| {
        n[0].lo[0][0] = 255;
        n[0].hi[0][0] = 0;
    });
    fails("reserved node bytes", &|n, _| n[0].reserved[3] = 1);
    fails("a group with no lanes", &|_, g| g[0].count = 0);
    fails("a group with nine lanes", &|_, g| g[0].count = 9);
    fails("a corner slot past 8", &|_, g| g[0].tri[1][0] = 8);
    fails("an unused lane with a corner", &|_, g| {
        let i = g.iter().position(|x| x.count < 8).unwrap();
        g[i].tri[2][7] = 1;
    });
    fails("a non-finite corner", &|_, g| g[0].corner[0][0] = f32::NAN);
    fails("an unused corner slot not zero", &|_, g| {
        let used = |x: &TriGroup| {
            x.tri
                .iter()
                .flat_map(|r| &r[..x.count as usize])
                .max()
                .copied()
        };
        let i = g.iter().position(|x| used(x) < Some(7)).unwrap();
        g[i].corner[1][7] = 1.0;
    });
    // A triangle moved outside its boxes (its corner pulled far away along x).
    fails("a triangle outside its boxes", &|_, g| {
        let j = g[0].tri[0][0] as usize;
        g[0].corner[0][j] += 1000.0;
    });
    fails("root past the end", &|n, _| n.clear());
}
