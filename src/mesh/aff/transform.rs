//! Affine maps: the `T R S` of a transform and their composition down the transform stack.

/// An affine map: rows of `[R | t]`.
pub(super) type Affine = [[f64; 4]; 3];

pub(super) const IDENTITY: Affine = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
];

/// `T R S`.
pub(super) fn trs(t: [f64; 3], r: [[f64; 3]; 3], s: [f64; 3]) -> Affine {
    std::array::from_fn(|i| [r[i][0] * s[0], r[i][1] * s[1], r[i][2] * s[2], t[i]])
}

pub(super) fn compose(a: &Affine, b: &Affine) -> Affine {
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

pub(super) fn apply(m: &Affine, p: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3])
}

#[cfg(test)]
mod tests {
    use super::super::kb::Quat;
    use super::*;

    #[test]
    fn trs_scales_then_rotates_then_translates() {
        let r = Quat::from_angle_axis(90f64.to_radians(), [0.0, 0.0, 1.0]).matrix();
        let m = trs([1.0, 2.0, 3.0], r, [2.0, 1.0, 1.0]);
        let p = apply(&m, [1.0, 0.0, 0.0]);
        let want = [1.0, 4.0, 3.0];
        assert!(
            p.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-12),
            "{p:?}"
        );
        let twice = compose(&m, &m);
        let q = apply(&twice, [1.0, 0.0, 0.0]);
        let want = apply(&m, apply(&m, [1.0, 0.0, 0.0]));
        assert!(q.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-12));
    }
}
