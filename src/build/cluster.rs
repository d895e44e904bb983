//! TEMPORARY linear cluster builder (to be replaced by the SAH builder of branch cluster-build).

use crate::physical::format::*;

pub struct ClusterTri {
    pub v: [[f32; 3]; 3],
    pub prim: u32,
}

pub struct ClusterBuild {
    pub nodes: Vec<ClusterNode>,
    pub groups: Vec<TriGroup>,
}

fn bbox(t: &ClusterTri, clip: &([f64; 3], [f64; 3])) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for v in &t.v {
        for k in 0..3 {
            lo[k] = lo[k].min(v[k]);
            hi[k] = hi[k].max(v[k]);
        }
    }
    for k in 0..3 {
        let cl = clip.0[k] as f32;
        let cl = if (cl as f64) > clip.0[k] {
            cl.next_down()
        } else {
            cl
        };
        let ch = clip.1[k] as f32;
        let ch = if (ch as f64) < clip.1[k] {
            ch.next_up()
        } else {
            ch
        };
        lo[k] = lo[k].max(cl).min(hi[k]);
        hi[k] = hi[k].min(ch).max(lo[k]);
    }
    (lo, hi)
}

fn union(a: ([f32; 3], [f32; 3]), b: ([f32; 3], [f32; 3])) -> ([f32; 3], [f32; 3]) {
    (
        std::array::from_fn(|k| a.0[k].min(b.0[k])),
        std::array::from_fn(|k| a.1[k].max(b.1[k])),
    )
}

const EMPTY: ([f32; 3], [f32; 3]) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);

fn quantise(boxes: &[([f32; 3], [f32; 3])]) -> ([f32; 3], [i8; 3], Vec<[[u8; 2]; 3]>) {
    let all = boxes.iter().fold(EMPTY, |a, &b| union(a, b));
    let mut origin = [0f32; 3];
    let mut exp = [0i8; 3];
    for k in 0..3 {
        let (lo, hi) = (all.0[k] as f64, all.1[k] as f64);
        let mut e = -100i32;
        loop {
            let step = 2f64.powi(e);
            let o = (lo / step).floor() * step;
            if ((hi - o) / step).ceil() <= 255.0 && (o / step).abs() + 256.0 < (1u64 << 24) as f64 {
                origin[k] = o as f32;
                exp[k] = e as i8;
                break;
            }
            e += 1;
        }
    }
    let q = boxes
        .iter()
        .map(|b| {
            std::array::from_fn(|k| {
                let step = 2f64.powi(exp[k] as i32);
                let lo = ((b.0[k] as f64 - origin[k] as f64) / step).floor();
                let hi = ((b.1[k] as f64 - origin[k] as f64) / step).ceil();
                [lo.clamp(0.0, 255.0) as u8, hi.clamp(0.0, 255.0) as u8]
            })
        })
        .collect();
    (origin, exp, q)
}

pub fn build_cluster(
    tris: &[ClusterTri],
    clip: ([f64; 3], [f64; 3]),
    node_base: u32,
    group_base: u32,
) -> Result<ClusterBuild, String> {
    // Groups: triangles in input order, greedily.
    let mut groups: Vec<TriGroup> = Vec::new();
    let mut gboxes = Vec::new();
    let mut order: Vec<usize> = (0..tris.len()).collect();
    let cen = |t: &ClusterTri| -> [f32; 3] {
        std::array::from_fn(|k| (t.v[0][k] + t.v[1][k] + t.v[2][k]) / 3.0)
    };
    let all = tris.iter().fold(EMPTY, |a, t| union(a, bbox(t, &clip)));
    order.sort_by_key(|&i| {
        let c = cen(&tris[i]);
        let q: [u32; 3] = std::array::from_fn(|k| {
            let e = (all.1[k] - all.0[k]).max(1e-30);
            (((c[k] - all.0[k]) / e).clamp(0.0, 1.0) * 1023.0) as u32
        });
        crate::mapping::morton::encode(q)
    });
    let mut g = TriGroup::zeroed();
    let mut corners: Vec<[u32; 3]> = Vec::new();
    let mut gb = EMPTY;
    for &i in &order {
        let t = &tris[i];
        let mut new: Vec<[u32; 3]> = Vec::new();
        for v in &t.v {
            let key = v.map(f32::to_bits);
            if !corners.contains(&key) && !new.contains(&key) {
                new.push(key);
            }
        }
        if g.count == 8 || corners.len() + new.len() > 8 {
            groups.push(g);
            gboxes.push(gb);
            g = TriGroup::zeroed();
            corners.clear();
            gb = EMPTY;
        }
        let l = g.count as usize;
        for (c, v) in t.v.iter().enumerate() {
            let key = v.map(f32::to_bits);
            let j = match corners.iter().position(|x| *x == key) {
                Some(j) => j,
                None => {
                    corners.push(key);
                    let j = corners.len() - 1;
                    for k in 0..3 {
                        g.corner[k][j] = v[k];
                    }
                    j
                }
            };
            g.tri[c][l] = j as u8;
        }
        g.prim[l] = t.prim;
        g.count += 1;
        gb = union(gb, bbox(t, &clip));
    }
    groups.push(g);
    gboxes.push(gb);

    // Nodes bottom-up: level 0 children are groups.
    // Build levels: each level is a list of (box, Child) where Child is Leaf(group) or Node(idx in level list).
    #[derive(Clone, Copy)]
    enum Ch {
        Leaf(usize),
        Inner(usize),
    }
    let mut level: Vec<(([f32; 3], [f32; 3]), Ch)> = gboxes
        .iter()
        .enumerate()
        .map(|(i, &b)| (b, Ch::Leaf(i)))
        .collect();
    // Each built node: list of children.
    let mut built: Vec<Vec<(([f32; 3], [f32; 3]), Ch)>> = Vec::new();
    loop {
        let mut next = Vec::new();
        for chunk in level.chunks(8) {
            let b = chunk.iter().fold(EMPTY, |a, c| union(a, c.0));
            built.push(chunk.to_vec());
            next.push((b, Ch::Inner(built.len() - 1)));
        }
        if next.len() == 1 {
            break;
        }
        level = next;
    }
    // Lay out breadth-first from the root (last built).
    let root = built.len() - 1;
    let mut queue = vec![root];
    let mut pos = vec![usize::MAX; built.len()];
    pos[root] = 0;
    let mut qi = 0;
    let mut out_order = Vec::new();
    // Group order: leaves in the order they are laid out.
    let mut group_order: Vec<usize> = Vec::new();
    let mut nodes: Vec<ClusterNode> = Vec::new();
    let mut next_pos = 1usize;
    while qi < queue.len() {
        let b = queue[qi];
        qi += 1;
        out_order.push(b);
        let children = &built[b];
        let inner: Vec<_> = children
            .iter()
            .filter(|c| matches!(c.1, Ch::Inner(_)))
            .collect();
        let leaves: Vec<_> = children
            .iter()
            .filter(|c| matches!(c.1, Ch::Leaf(_)))
            .collect();
        let mut n = ClusterNode::zeroed();
        n.child_count = children.len() as u8;
        n.inner_count = inner.len() as u8;
        n.node_base = node_base + next_pos as u32;
        n.group_base = group_base + group_order.len() as u32;
        let boxes: Vec<_> = inner.iter().chain(leaves.iter()).map(|c| c.0).collect();
        let (o, e, q) = quantise(&boxes);
        n.origin = o;
        n.exp = e;
        for (i, qb) in q.iter().enumerate() {
            for k in 0..3 {
                n.lo[k][i] = qb[k][0];
                n.hi[k][i] = qb[k][1];
            }
        }
        for c in &inner {
            if let Ch::Inner(x) = c.1 {
                pos[x] = next_pos;
                next_pos += 1;
                queue.push(x);
            }
        }
        for c in &leaves {
            if let Ch::Leaf(x) = c.1 {
                group_order.push(x);
            }
        }
        nodes.push(n);
    }
    let groups = group_order.iter().map(|&i| groups[i]).collect();
    Ok(ClusterBuild { nodes, groups })
}

use bytemuck::Zeroable;
