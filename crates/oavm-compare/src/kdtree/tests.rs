use super::build::{event_order, f32_down, f32_up, push_events, sweep};
use super::*;
use crate::Counters;
use crate::test_util::{
    check, flat_mesh_and_rays, ranged_rays, rng, tris_of, unit_rays, unit_soup,
};
use crate::{Accelerator, Triangles};
use oavm::geom::{Hit, Ray};
use rayon::prelude::*;

/// Every triangle is referenced by some leaf, and the tree respects its depth limit.
fn check_structure(kd: &KdTree, n: usize) {
    assert!(!kd.brute);
    let (depth, leaves) = kd.depth_and_leaves();
    assert!(depth <= kd.max_depth(), "{depth} > {}", kd.max_depth());
    assert_eq!(leaves, kd.nodes.iter().filter(|x| x.is_leaf()).count());
    let mut seen = vec![false; n];
    for nd in kd.nodes.iter().filter(|x| x.is_leaf()) {
        assert_eq!(kd.leaf_list(nd).len(), nd.upper() as usize, "{nd:?}");
        for &i in kd.leaf_list(nd) {
            seen[i as usize] = true;
        }
    }
    assert!(seen.iter().all(|&s| s), "a triangle is in no leaf");
}

#[test]
fn random_soup_matches_brute_force() {
    let (tris, mesh) = tris_of(unit_soup(800, 11));
    let kd = KdTree::build(&tris);
    check_structure(&kd, 800);
    let s = kd.stats();
    assert!(s.nodes > 100 && s.pointers > 50, "{s:?}");
    check(&kd, &mesh, &unit_rays(5000, 12), 800);
}

/// `bytes` counts the tree's own record: its size is part of the figures `oavm-bench` reports.
#[test]
#[cfg(target_pointer_width = "64")]
fn bytes_count_the_record_the_nodes_the_lists_and_the_triangles() {
    assert_eq!(std::mem::size_of::<KdTree>(), 296);
    let (tris, _) = tris_of(unit_soup(300, 3));
    let kd = KdTree::build(&tris);
    let want = 296 + 8 * kd.nodes.len() + 4 * kd.leaf_prims.len() + 40 * tris.len();
    assert_eq!(kd.stats().bytes, want as u64);
}

#[test]
fn event_sweep_counts_planar_triangles() {
    // Two triangles flat in x at x = 0.5 and one spanning [0, 1]: at the plane x = 0.5 the
    // sweep sees 1 triangle on the left, 2 planar and 1 on the right.
    let mut ev = Vec::new();
    push_events(&mut ev, 0, [0.5, 0.0, 0.0], [0.5, 1.0, 1.0]);
    push_events(&mut ev, 1, [0.5, 0.0, 0.0], [0.5, 1.0, 1.0]);
    push_events(&mut ev, 2, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]);
    ev.sort_by(event_order);
    let s = sweep(&ev, 3, [0.0; 3], [1.0; 3]).unwrap();
    assert_eq!((s.axis, s.pos), (0, 0.5));
    // Both sides cost the same; ties go left.
    assert!(s.planar_left);
    assert!(s.cost < ISECT_COST * 3.0);
}

#[test]
fn empty_single_and_invalid() {
    let kd = KdTree::build(&Triangles::default());
    let r = Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, f32::INFINITY);
    let mut c = Counters::default();
    assert_eq!(kd.intersect(&r, &mut c), Hit::MISS);
    assert!(!kd.occluded(&r, &mut c));
    assert_eq!(kd.stats().nodes, 0);

    let (tris, mesh) = tris_of(vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]]);
    let kd = KdTree::build(&tris);
    assert_eq!(kd.stats().nodes, 1);
    assert_eq!(kd.stats().pointers, 0);
    let down = Ray::new([0.25, 0.25, 1.0], [0.0, 0.0, -1.0], 0.0, f32::INFINITY);
    assert_eq!(kd.intersect(&down, &mut c), Hit { t: 1.0, prim: 0 });
    check(&kd, &mesh, &unit_rays(2000, 13), 20);
    let bad = Ray::new([0.25, 0.25, 1.0], [f32::NAN, 0.0, -1.0], 0.0, 9.0);
    assert_eq!(kd.intersect(&bad, &mut c), Hit::MISS);
    assert!(!kd.occluded(&bad, &mut c));
}

#[test]
fn flat_mesh_and_planes_of_triangles_on_split_planes() {
    let mut r = rng(14);
    let (flat, rays) = flat_mesh_and_rays(&mut r, 600, 0.04, 3000, true);
    let (tris, mesh) = tris_of(flat);
    let kd = KdTree::build(&tris);
    check_structure(&kd, 600);
    assert!(kd.stats().nodes > 50);
    check(&kd, &mesh, &rays, 500);

    // Soup plus stacks of triangles flat in x at x = 0.25, 0.5, 0.75 (planar events, likely
    // split planes) and triangles meeting them edge-on; rays along every axis and slanted,
    // starting inside the tree.
    let mut v = unit_soup(300, 15);
    for &x in &[0.25f32, 0.5, 0.75] {
        for i in 0..100 {
            let (y, z) = ((i % 10) as f32 / 10.0, (i / 10) as f32 / 10.0);
            v.push([[x, y, z], [x, y + 0.1, z], [x, y, z + 0.1]]);
            v.push([[x, y, z], [x + 0.05, y + 0.1, z], [x, y, z + 0.1]]);
        }
    }
    let n = v.len();
    let (tris, mesh) = tris_of(v);
    let kd = KdTree::build(&tris);
    check_structure(&kd, n);
    let mut rays = Vec::new();
    for i in 0..6000 {
        let o = [r(), r(), r()];
        let mut d = [r() - 0.5, r() - 0.5, r() - 0.5];
        if i % 2 == 0 {
            d = [0.0; 3];
            d[i / 2 % 3] = if i % 4 == 0 { 1.0 } else { -1.0 };
        }
        rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
        // Rays lying in the planes.
        let o = [[0.25f32, 0.5, 0.75][i % 3], r(), r()];
        let d = [0.0, r() - 0.5, r() - 0.5];
        rays.push(Ray::new(o, d, 0.0, f32::INFINITY));
    }
    check(&kd, &mesh, &rays, 2000);
}

#[test]
fn range_limits_and_negative_tmin() {
    let (tris, mesh) = tris_of(unit_soup(400, 16));
    let kd = KdTree::build(&tris);
    let rays = ranged_rays(3000, 17, [-1.0, 1.0]);
    check(&kd, &mesh, &rays, 300);
}

#[test]
fn depth_is_limited_on_a_pathological_stack() {
    // 2000 identical-footprint triangles stacked along z: splits cannot separate many of
    // them cheaply, so bad refines and the depth limit must end the recursion.
    let v: Vec<_> = (0..2000)
        .map(|i| {
            let z = i as f32 * 1e-3;
            [[0.0, 0.0, z], [1.0, 0.0, z + 0.5], [0.0, 1.0, z + 0.25]]
        })
        .collect();
    let (tris, mesh) = tris_of(v);
    let kd = KdTree::build(&tris);
    check_structure(&kd, 2000);
    assert_eq!(kd.max_depth(), (8.0 + 1.3 * 10.0f64).round() as u32);
    let mut c = Counters::default();
    check(&kd, &mesh, &unit_rays(500, 18), 50);
    let r = Ray::new([0.1, 0.1, -1.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY);
    let h = kd.intersect(&r, &mut c);
    assert!(h.is_hit());
    assert!(c.nodes_visited >= c.leaves_visited && c.leaves_visited >= 1);
    assert_eq!(c.rays, 0);
}

#[test]
fn outward_rounding() {
    let x = 0.1f64;
    assert!((f32_down(x) as f64) <= x && (f32_up(x) as f64) >= x);
    assert!(f32_down(x) < f32_up(x));
    assert_eq!(f32_down(0.5), 0.5);
    assert_eq!(f32_up(0.5), 0.5);
}

/// The traversal variants the stackless comparison needs, with the short stack at several
/// sizes.
fn variants() -> Vec<KdTraversal> {
    let mut v = vec![KdTraversal::Restart, KdTraversal::PushDown];
    v.extend([1, 2, 4, 8].map(KdTraversal::ShortStack));
    v.extend([
        KdTraversal::Ropes,
        KdTraversal::Popov,
        KdTraversal::SplitStack,
    ]);
    v
}

/// Every variant agrees with the f64 brute force (closest and any hit) and with the stack walk
/// ray for ray (the same triangle at the same `t`; rays grazing an edge aside, where a walk
/// down again from a leaf's exit may not revisit the side it left, as [`check`] sets them
/// aside), on random soups, on the flat-plane scene (rays lying in split planes take the stack
/// walk) and on awkward rays; the stackless ones restart, push-down visits fewer nodes than
/// kd-restart, and a deeper short stack restarts less.
#[test]
fn traversal_variants_match_brute_force_and_the_stack_walk() {
    use crate::test_util::awkward_rays;
    let scenes = soup_and_planes(31, 15);
    for (s, (tris, mesh)) in scenes.iter().enumerate() {
        let stack = KdTree::build(tris);
        let mut rays = unit_rays(3000, 40 + s as u64);
        rays.extend(awkward_rays(tris, 1500, 50 + s as u64));
        let mut reference = Counters::default();
        let want: Vec<(Hit, bool)> = rays
            .iter()
            .map(|r| {
                (
                    stack.intersect(r, &mut reference),
                    stack.occluded(r, &mut reference),
                )
            })
            .collect();
        let visited: Vec<(KdTraversal, u64, u64)> = variants()
            .into_par_iter()
            .map(|t| {
                let kd = KdTree::build(tris).with_traversal(t);
                assert_eq!(kd.stats().name, t.name());
                check(&kd, mesh, &rays, 1000);
                let mut c = Counters::default();
                let corners = mesh.corners();
                for (r, w) in rays.iter().zip(&want) {
                    let got = (kd.intersect(r, &mut c), kd.occluded(r, &mut c));
                    if got != *w {
                        assert!(
                            oavm::geom::reference::grazes(&corners, r),
                            "scene {s}, {t:?}, {r:?}: {got:?}, the stack walk {w:?}"
                        );
                    }
                }
                if !matches!(t, KdTraversal::ShortStack(2..)) {
                    assert!(c.restarts > 0, "scene {s}, {t:?}: {c:?}");
                }
                (t, c.nodes_visited, c.restarts)
            })
            .collect();
        let nodes = |t: KdTraversal| visited.iter().find(|v| v.0 == t).unwrap().1;
        assert!(
            nodes(KdTraversal::PushDown) < nodes(KdTraversal::Restart),
            "scene {s}: {visited:?}"
        );
        // A deeper short stack restarts less.
        let restarts = |t: KdTraversal| visited.iter().find(|v| v.0 == t).unwrap().2;
        assert!(
            restarts(KdTraversal::ShortStack(8)) < restarts(KdTraversal::ShortStack(1))
                && restarts(KdTraversal::ShortStack(1)) <= restarts(KdTraversal::Restart),
            "scene {s}: {visited:?}"
        );
        eprintln!(
            "scene {s}: stack {} nodes; {visited:?}",
            reference.nodes_visited
        );
    }
}

/// Every rope of a leaf names a node across that face: its cell starts where the leaf's ends
/// on the face's axis and meets the face's rectangle; Popov's ropes name a node whose cell
/// holds the whole face, and no larger node than the source's. The ropes' bytes and pointers
/// are counted.
#[test]
fn ropes_name_the_node_across_each_face() {
    let (tris, _) = tris_of(unit_soup(1200, 61));
    let plain = KdTree::build(&tris);
    let leaves = plain.nodes.iter().filter(|n| n.is_leaf()).count();
    let src = KdTree::build(&tris).with_traversal(KdTraversal::Ropes);
    let popov = KdTree::build(&tris).with_traversal(KdTraversal::Popov);
    for kd in [&src, &popov] {
        assert_eq!(
            kd.stats().bytes,
            plain.stats().bytes + 48 * plain.nodes.len() as u64
        );
        assert_eq!(
            kd.stats().pointers,
            plain.stats().pointers + 6 * leaves as u64
        );
    }
    let (rs, rp) = (src.ropes.as_ref().unwrap(), popov.ropes.as_ref().unwrap());
    let (mut boundary, mut pushed) = (0, 0);
    for (i, n) in src.nodes.iter().enumerate() {
        if !n.is_leaf() {
            continue;
        }
        let leaf = rs.cell[i];
        for f in 0..6 {
            let (a, high) = (f / 2, f % 2 == 1);
            let (s, p) = (rs.across[i][f], rp.across[i][f]);
            assert_eq!(s == ropes::NONE, p == ropes::NONE, "leaf {i} face {f}");
            if s == ropes::NONE {
                // Only at the scene's boundary.
                let edge = if high { src.hi[a] } else { src.lo[a] } as f32;
                assert_eq!(if high { leaf[1][a] } else { leaf[0][a] }, edge);
                boundary += 1;
                continue;
            }
            for (t, whole) in [(s, false), (p, true)] {
                let c = rs.cell[t as usize];
                if high {
                    assert_eq!(c[0][a], leaf[1][a], "leaf {i} face {f} -> {t}");
                } else {
                    assert_eq!(c[1][a], leaf[0][a], "leaf {i} face {f} -> {t}");
                }
                for k in (0..3).filter(|&k| k != a) {
                    assert!(c[0][k] < leaf[1][k] && c[1][k] > leaf[0][k], "meets");
                    if whole {
                        assert!(c[0][k] <= leaf[0][k] && c[1][k] >= leaf[1][k], "holds");
                    }
                }
            }
            pushed += (p != s) as usize;
        }
    }
    assert!(
        boundary > 0 && pushed > leaves,
        "{boundary} {pushed} {leaves}"
    );
}

/// Two scenes for the traversal variants: a random soup (seed `soup`), and a smaller soup (seed
/// `planes`) with 300 triangles lying in the planes x = 0.25, 0.5, 0.75, where a ray can lie in a
/// split plane.
fn soup_and_planes(soup: u64, planes: u64) -> Vec<(Triangles, oavm::mesh::Mesh)> {
    let mut v = unit_soup(300, planes);
    for &x in &[0.25f32, 0.5, 0.75] {
        for i in 0..100 {
            let (y, z) = ((i % 10) as f32 / 10.0, (i / 10) as f32 / 10.0);
            v.push([[x, y, z], [x, y + 0.1, z], [x, y, z + 0.1]]);
        }
    }
    vec![tris_of(unit_soup(1500, soup)), tris_of(v)]
}

/// The `SplitStack` walk is the stack walk: on random soups, on the flat-plane scene (rays
/// lying in split planes) and on awkward rays, every ray gets the stack walk's closest and any
/// hit (grazing or not), and a ray not parallel to an axis (which cannot lie in a split plane)
/// visits the same nodes and leaves and tests the same triangles; it takes ropes.
#[test]
fn split_stack_walk_is_the_stack_walk() {
    use crate::test_util::awkward_rays;
    let scenes = soup_and_planes(71, 72);
    for (s, (tris, mesh)) in scenes.iter().enumerate() {
        let stack = KdTree::build(tris);
        let walk = KdTree::build(tris).with_traversal(KdTraversal::SplitStack);
        assert_eq!(walk.stats().name, "kdtree:splitstack");
        let mut rays = unit_rays(3000, 73 + s as u64);
        rays.extend(awkward_rays(tris, 1500, 75 + s as u64));
        check(&walk, mesh, &rays, 1000);
        let (mut same_counts, mut restarts) = (0, 0);
        for r in &rays {
            let (mut a, mut b) = (Counters::default(), Counters::default());
            let want = (stack.intersect(r, &mut a), stack.occluded(r, &mut a));
            let got = (walk.intersect(r, &mut b), walk.occluded(r, &mut b));
            assert_eq!(got, want, "scene {s}, {r:?}");
            restarts += b.restarts;
            b.restarts = 0;
            if r.dir.iter().all(|&d| d != 0.0) {
                assert_eq!(b, a, "scene {s}, {r:?}");
                same_counts += 1;
            }
        }
        assert!(same_counts > rays.len() / 2 && restarts > 1000, "scene {s}");
    }
}

/// The `SplitStack` walk's ropes are the source's, named by their forks and kept for every
/// node: each names the node whose split plane forms that face of the node's cell (none at the
/// scene's boundary), and across a leaf's face the fork's far child is the source's rope. They
/// cost 24 bytes and six pointers a node, and no cells.
#[test]
fn split_stack_ropes_name_the_fork_forming_each_face() {
    let (tris, _) = tris_of(unit_soup(1200, 62));
    let plain = KdTree::build(&tris);
    let src = KdTree::build(&tris).with_traversal(KdTraversal::Ropes);
    let kd = KdTree::build(&tris).with_traversal(KdTraversal::SplitStack);
    let nodes = plain.nodes.len() as u64;
    assert_eq!(kd.stats().bytes, plain.stats().bytes + 24 * nodes);
    assert_eq!(kd.stats().pointers, plain.stats().pointers + 6 * nodes);
    let (rs, rk) = (src.ropes.as_ref().unwrap(), kd.ropes.as_ref().unwrap());
    assert!(rk.cell.is_empty());
    let mut interior = 0;
    for (i, n) in kd.nodes.iter().enumerate() {
        let cell = rs.cell[i];
        for f in 0..6 {
            let (a, high) = (f / 2, f % 2 == 1);
            let face = if high { cell[1][a] } else { cell[0][a] };
            let q = rk.across[i][f];
            if q == ropes::NONE {
                let edge = if high { kd.hi[a] } else { kd.lo[a] } as f32;
                assert_eq!(face, edge, "node {i} face {f}");
                if n.is_leaf() {
                    assert_eq!(rs.across[i][f], ropes::NONE);
                }
                continue;
            }
            let fork = kd.nodes[q as usize];
            assert!(
                !fork.is_leaf() && (q as usize) < i,
                "node {i} face {f}: {q}"
            );
            assert_eq!((fork.axis(), fork.split()), (a, face), "node {i} face {f}");
            let across = if high { fork.upper() } else { q + 1 };
            if n.is_leaf() {
                assert_eq!(across, rs.across[i][f], "leaf {i} face {f}");
            } else {
                interior += 1;
            }
        }
    }
    assert!(interior > 100);
}

/// More forks pending than the `SplitStack` register holds. Real trees hardly have them (the
/// kitchen, the robots and a 32^3 lattice of small triangles, depth 28, had none), so the tree
/// is made by hand: `forks` splits on x at 1/2, 1/4, ..., each with an empty leaf above but the
/// first (a triangle at x = 0.75), and rays along +x, which fork at every split. With 21 forks
/// the walk is the stack walk; with 25 it finishes with the stack walk from the root.
#[test]
fn split_stack_walk_past_its_register_takes_the_stack_walk() {
    let (tris, _) = tris_of(vec![
        [[0.75, 0.0, 0.0], [0.75, 1.0, 0.0], [0.75, 0.0, 1.0]],
        [[0.0, 0.9, 0.9], [0.0, 1.0, 0.9], [0.0, 0.9, 1.0]],
    ]);
    for forks in [SPLIT_STACK_FORKS, SPLIT_STACK_FORKS + 4] {
        // Depth first: the forks, the leaf below the last (the second triangle, at x = 0), then
        // the leaves above them, the last fork's first.
        let mut nodes: Vec<KdNode> = (0..forks)
            .map(|i| KdNode::interior(0, 0.5f32.powi(i as i32 + 1), (2 * forks - i) as u32))
            .collect();
        nodes.push(KdNode::leaf(1, 1));
        for i in (0..forks).rev() {
            nodes.push(KdNode::leaf((i == 0) as u32, 0));
        }
        let with = |t: KdTraversal| {
            let mut kd = KdTree::build(&tris);
            kd.nodes = nodes.clone();
            kd.leaf_prims.clear();
            kd.with_traversal(t)
        };
        let (stack, walk) = (with(KdTraversal::Stack), with(KdTraversal::SplitStack));
        for k in 0..10 {
            let y = 0.1 + 0.05 * k as f32;
            let ray = Ray::new([-1.0, y, 0.2], [1.0, 0.0, 0.0], 0.0, f32::INFINITY);
            let (mut a, mut b) = (Counters::default(), Counters::default());
            let want = stack.intersect(&ray, &mut a);
            assert!(want.prim == 0 && (want.t - 1.75).abs() < 1e-6, "{want:?}");
            assert_eq!(walk.intersect(&ray, &mut b), want, "{forks} forks, {ray:?}");
            assert!(walk.occluded(&ray, &mut Counters::default()));
            // Past the register, walked again from the root: more nodes than the stack walk.
            assert_eq!(
                b.nodes_visited > a.nodes_visited,
                forks > SPLIT_STACK_FORKS,
                "{forks} forks: {a:?} {b:?}"
            );
        }
    }
}

/// OAVM's occluders (`pack::occluders`) estimate costs with the SAH constants of this tree's
/// build, so that the two primitive indices are chosen alike.
#[test]
fn occluders_share_the_sah_constants() {
    assert_eq!(oavm::pack::occluders::ISECT_COST, super::ISECT_COST);
    assert_eq!(oavm::pack::occluders::TRAVERSAL_COST, super::TRAVERSAL_COST);
}
