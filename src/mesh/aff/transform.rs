//! Affine maps: the `T R S` of a transform and their composition down the transform stack, in
//! glam's `DAffine3` (`x' = M x + t`, `M` by columns).
//!
//! Posing must keep its bits (the BART scenes' digests in `tests/integration/mesh_aff.rs` pin them), and
//! these glam operations compute exactly what the row-by-row code before them did, in the same
//! order: `DAffine3 * DAffine3` forms each entry as `(a0 b0 + a1 b1) + a2 b2` (then `+ t` for
//! the translation), and `transform_point3` each coordinate as `((m0 x + m1 y) + m2 z) + t`.

use glam::{DAffine3, DMat3, DVec3};

pub(super) type Affine = DAffine3;

pub(super) const IDENTITY: Affine = DAffine3::IDENTITY;

/// `T R S`, for a rotation `r` given by rows (as [`super::kb::Quat::matrix`] gives it).
///
/// Each column of `R` is scaled on its own: `DMat3 * DMat3::from_diagonal(s)` would add
/// products with zero, turning a `-0.0` entry into `+0.0`.
pub(super) fn trs(t: DVec3, r: [[f64; 3]; 3], s: DVec3) -> Affine {
    let column = |j: usize| DVec3::new(r[0][j], r[1][j], r[2][j]);
    DAffine3 {
        matrix3: DMat3::from_cols(column(0) * s.x, column(1) * s.y, column(2) * s.z),
        translation: t,
    }
}

/// `a` after `b`: the parent's transform `a` composed with the child's `b`.
pub(super) fn compose(a: &Affine, b: &Affine) -> Affine {
    *a * *b
}

pub(super) fn apply(m: &Affine, p: DVec3) -> DVec3 {
    m.transform_point3(p)
}

#[cfg(test)]
mod tests {
    use super::super::kb::Quat;
    use super::*;

    #[test]
    fn trs_scales_then_rotates_then_translates() {
        let r = Quat::from_angle_axis(90f64.to_radians(), [0.0, 0.0, 1.0]).matrix();
        let m = trs(DVec3::new(1.0, 2.0, 3.0), r, DVec3::new(2.0, 1.0, 1.0));
        let p = apply(&m, DVec3::X);
        assert!(p.abs_diff_eq(DVec3::new(1.0, 4.0, 3.0), 1e-12), "{p:?}");
        let twice = compose(&m, &m);
        let q = apply(&twice, DVec3::X);
        assert!(q.abs_diff_eq(apply(&m, apply(&m, DVec3::X)), 1e-12));
    }

    /// The row-by-row arithmetic glam replaced, for the bit comparison below.
    fn rows(m: &Affine) -> [[f64; 4]; 3] {
        let c = m.to_cols_array();
        std::array::from_fn(|i| [c[i], c[3 + i], c[6 + i], c[9 + i]])
    }

    fn compose_rows(a: &[[f64; 4]; 3], b: &[[f64; 4]; 3]) -> [[f64; 4]; 3] {
        std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                let mut v = (0..3).map(|k| a[i][k] * b[k][j]).sum::<f64>();
                if j == 3 {
                    v += a[i][3];
                }
                v
            })
        })
    }

    fn trs_rows(t: [f64; 3], r: [[f64; 3]; 3], s: [f64; 3]) -> [[f64; 4]; 3] {
        std::array::from_fn(|i| [r[i][0] * s[0], r[i][1] * s[1], r[i][2] * s[2], t[i]])
    }

    fn apply_rows(m: &[[f64; 4]; 3], p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3])
    }

    #[test]
    fn glam_composes_and_applies_with_the_bits_of_the_row_code() {
        let mut state = 1u64;
        let mut r = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            // Mostly ordinary values, sometimes signed zeros.
            match state >> 60 {
                0 => 0.0,
                1 => -0.0,
                _ => ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 1e3,
            }
        };
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for _ in 0..2000 {
            let q = Quat::from_angle_axis(r(), [r(), r(), r()]).matrix();
            let (t, s) = ([r(), r(), r()], [r(), r(), r()]);
            let a = trs(DVec3::from_array(t), q, DVec3::from_array(s));
            let want = trs_rows(t, q, s);
            assert_eq!(bits(rows(&a).as_flattened()), bits(want.as_flattened()));
            let q = Quat::from_angle_axis(r(), [r(), r(), r()]).matrix();
            let b = trs(DVec3::new(r(), r(), r()), q, DVec3::new(r(), r(), r()));
            let ab = compose(&a, &b);
            let want = compose_rows(&rows(&a), &rows(&b));
            assert_eq!(bits(rows(&ab).as_flattened()), bits(want.as_flattened()));
            let p = [r(), r(), r()];
            let got = apply(&ab, DVec3::from_array(p)).to_array();
            assert_eq!(bits(&got), bits(&apply_rows(&want, p)));
        }
    }
}
