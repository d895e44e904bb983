//! The format 4 kernels on the records: `geom` cannot name `physical`'s records (it is below in
//! the module stack), so its kernels read views of them (`TriGroupView`, `ClusterNodeView`).
//! This checks that a view of a record means what the record says: the same triangles as
//! `TriGroup::triangle`, the same boxes as `ClusterNode::child_box`, and kernel answers equal
//! to the scalar test on the record's own triangles, for any bytes.

use oavm::geom::triangle::RayShear;
use oavm::geom::{BoxRay, ClusterNodeView, Ray, TriGroupView};
use oavm::os::Avx2;
use oavm::physical::format::{CLUSTER_EXP_RANGE, ClusterNode, TriGroup};

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn small(&mut self) -> f32 {
        (self.next() % 9) as f32 * 0.5 - 2.0
    }
}

fn group_view(g: &TriGroup) -> TriGroupView<'_> {
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

#[test]
fn a_group_view_is_the_record() {
    let mut r = Rng(11);
    let avx2 = Avx2::detect();
    for _ in 0..20_000 {
        // Any slot bytes and count; small coordinates (shared corners, exact zeros).
        let bytes: Vec<u8> = (0..size_of::<TriGroup>()).map(|_| r.next() as u8).collect();
        let mut g: TriGroup = bytemuck::pod_read_unaligned(&bytes);
        for row in g.corner.iter_mut() {
            row.iter_mut().for_each(|c| *c = r.small());
        }
        g.count %= 10;
        let v = group_view(&g);
        for l in 0..8 {
            assert_eq!(v.triangle(l), g.triangle(l));
        }
        let ray = Ray::new(
            [r.small(), r.small(), r.small() + 3.0],
            [r.small() * 0.25, r.small() * 0.25, -1.0],
            0.0,
            f32::INFINITY,
        );
        let sh = RayShear::new(&ray);
        let want: Vec<Option<f32>> = (0..8)
            .map(|l| {
                let live = l < g.count as usize;
                live.then(|| sh.intersect(&g.triangle(l), ray.tmin, ray.tmax))
                    .flatten()
            })
            .collect();
        let mut answers = vec![sh.intersect_group(v, ray.tmin, ray.tmax)];
        if let Some(isa) = avx2 {
            answers.push(sh.intersect_group_avx2(isa, v, ray.tmin, ray.tmax));
        }
        for (mask, ts) in answers {
            for l in 0..8 {
                let got = (mask >> l & 1 == 1).then_some(ts[l]);
                assert_eq!(got.map(f32::to_bits), want[l].map(f32::to_bits), "{g:?}");
            }
        }
    }
}

#[test]
fn a_node_view_is_the_record() {
    let mut r = Rng(12);
    for _ in 0..20_000 {
        let bytes: Vec<u8> = (0..size_of::<ClusterNode>())
            .map(|_| r.next() as u8)
            .collect();
        let mut n: ClusterNode = bytemuck::pod_read_unaligned(&bytes);
        // The spec's exponents (outside them the view clamps where the record does not).
        for e in n.exp.iter_mut() {
            *e = (*e).clamp(*CLUSTER_EXP_RANGE.start(), *CLUSTER_EXP_RANGE.end());
        }
        let v = node_view(&n);
        for i in 0..8 {
            let (a, b) = (v.child_box(i), n.child_box(i));
            let bits = |x: [f32; 3]| x.map(f32::to_bits);
            assert_eq!((bits(a.0), bits(a.1)), (bits(b.0), bits(b.1)));
        }
        assert_eq!(v.live(), (1 << n.child_count.min(8)) - 1);
        // Any bytes: some answer, within the live children.
        let ray = Ray::new([r.small(); 3], [1.0, -0.5, 0.25], 0.0, f32::INFINITY);
        let (mask, _) = BoxRay::new(&ray).node_hits(v, ray.tmin, ray.tmax);
        assert_eq!(mask & !v.live(), 0);
    }
}
