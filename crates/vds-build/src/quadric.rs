//! Quadric error metrics for proxy placement.
//!
//! Garland & Heckbert, "Surface Simplification Using Quadric Error Metrics" (SIGGRAPH 1997):
//! each triangle contributes the squared distance to its plane, weighted by its area; a
//! cluster's quadric is the sum of its vertices' quadrics. The minimiser is found as in
//! Lindstrom, "Out-of-Core Simplification of Large Polygonal Models" (SIGGRAPH 2000): an
//! eigen-decomposition of the 3×3 part, with directions of tiny eigenvalue (flat or linear
//! clusters, where the minimiser is a plane or line) left at the cluster mean.

/// `E(v) = vᵀ A v + 2 bᵀ v + c`, with symmetric `A` stored as its upper triangle.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Quadric {
    /// `A`: xx, xy, xz, yy, yz, zz.
    pub a: [f64; 6],
    /// `b`.
    pub b: [f64; 3],
    /// `c`.
    pub c: f64,
}

/// Eigenvalues below this fraction of the largest are treated as zero: the solve then keeps
/// the cluster mean along those directions instead of sliding far along a flat region.
const RELATIVE_EIGEN_CUTOFF: f64 = 1e-3;

impl Quadric {
    /// The area-weighted quadric of the plane through a triangle (zero for a zero-area one).
    pub fn from_triangle(p0: [f64; 3], p1: [f64; 3], p2: [f64; 3]) -> Quadric {
        let n = cross(sub(p1, p0), sub(p2, p0));
        let twice_area = dot(n, n).sqrt();
        if twice_area == 0.0 {
            return Quadric::default();
        }
        Quadric::from_plane(n.map(|c| c / twice_area), p0, 0.5 * twice_area)
    }

    /// The quadric of the plane with unit normal `n` through `point`, weighted by `area`.
    pub fn from_plane(n: [f64; 3], point: [f64; 3], area: f64) -> Quadric {
        let d = -dot(n, point);
        let w = area;
        Quadric {
            a: [
                w * n[0] * n[0],
                w * n[0] * n[1],
                w * n[0] * n[2],
                w * n[1] * n[1],
                w * n[1] * n[2],
                w * n[2] * n[2],
            ],
            b: [w * n[0] * d, w * n[1] * d, w * n[2] * d],
            c: w * d * d,
        }
    }

    /// The quadric of planes that all pass through `point`, from their weighted normal
    /// moments `Σ w·n·nᵀ` (upper triangle, as `a`). With every `d = −n·point`, `b = Σ w·n·d`
    /// is `−A·point` and `c = Σ w·d²` is `pointᵀ·A·point`, so a vertex's quadric (all its
    /// triangles' planes pass through it) needs only the six moments per triangle.
    pub fn through_point(moments: [f64; 6], point: [f64; 3]) -> Quadric {
        let mut q = Quadric {
            a: moments,
            b: [0.0; 3],
            c: 0.0,
        };
        let ap = q.apply(point);
        q.b = ap.map(|x| -x);
        q.c = dot(point, ap);
        q
    }

    /// Adds another quadric.
    pub fn add(&mut self, other: &Quadric) {
        for k in 0..6 {
            self.a[k] += other.a[k];
        }
        for k in 0..3 {
            self.b[k] += other.b[k];
        }
        self.c += other.c;
    }

    /// The error at `v`.
    pub fn error(&self, v: [f64; 3]) -> f64 {
        let av = self.apply(v);
        dot(v, av) + 2.0 * dot(self.b, v) + self.c
    }

    fn apply(&self, v: [f64; 3]) -> [f64; 3] {
        let a = &self.a;
        [
            a[0] * v[0] + a[1] * v[1] + a[2] * v[2],
            a[1] * v[0] + a[3] * v[1] + a[4] * v[2],
            a[2] * v[0] + a[4] * v[1] + a[5] * v[2],
        ]
    }

    /// The point minimising the error, solved around `mean` along well-conditioned
    /// directions only (rank-truncated pseudo-inverse).
    // Inlined into the build's wide kernels (`crate::isa`), as is `symmetric_eigen`.
    #[inline(always)]
    pub fn minimizer_near(&self, mean: [f64; 3]) -> [f64; 3] {
        let (values, vectors) = symmetric_eigen(self.a);
        let largest = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if largest <= 0.0 || !largest.is_finite() {
            return mean;
        }
        // Gradient of E at the mean is 2(A·mean + b); step = -A⁺(A·mean + b).
        let residual = add(self.apply(mean), self.b);
        let mut point = mean;
        for k in 0..3 {
            if values[k] > RELATIVE_EIGEN_CUTOFF * largest {
                let u = vectors[k];
                let step = -dot(u, residual) / values[k];
                for i in 0..3 {
                    point[i] += step * u[i];
                }
            }
        }
        point
    }
}

/// Eigenvalues and unit eigenvectors of a symmetric 3×3 matrix (upper triangle
/// `xx, xy, xz, yy, yz, zz`), by cyclic Jacobi rotations.
#[inline(always)]
pub fn symmetric_eigen(upper: [f64; 6]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut m = [
        [upper[0], upper[1], upper[2]],
        [upper[1], upper[3], upper[4]],
        [upper[2], upper[4], upper[5]],
    ];
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    // Jacobi converges quadratically; 8 sweeps reach f64 precision for any 3×3 input.
    for _sweep in 0..8 {
        let off = m[0][1].abs() + m[0][2].abs() + m[1][2].abs();
        let scale = m[0][0].abs() + m[1][1].abs() + m[2][2].abs();
        if off <= 1e-15 * scale || off == 0.0 {
            break;
        }
        for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
            if m[p][q] == 0.0 {
                continue;
            }
            let theta = (m[q][q] - m[p][p]) / (2.0 * m[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for row in m.iter_mut() {
                let (x, y) = (row[p], row[q]);
                row[p] = c * x - s * y;
                row[q] = s * x + c * y;
            }
            for k in 0..3 {
                let (x, y) = (m[p][k], m[q][k]);
                m[p][k] = c * x - s * y;
                m[q][k] = s * x + c * y;
            }
            for row in v.iter_mut() {
                let (x, y) = (row[p], row[q]);
                row[p] = c * x - s * y;
                row[q] = s * x + c * y;
            }
        }
    }
    let values = [m[0][0], m[1][1], m[2][2]];
    let vectors = [
        [v[0][0], v[1][0], v[2][0]],
        [v[0][1], v[1][1], v[2][1]],
        [v[0][2], v[1][2], v[2][2]],
    ];
    (values, vectors)
}

pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(crate) fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corner_of_three_planes_is_recovered() {
        // Three orthogonal faces meeting at (1, 2, 3).
        let c = [1.0, 2.0, 3.0];
        let mut q = Quadric::default();
        q.add(&Quadric::from_triangle(
            c,
            add(c, [1.0, 0.0, 0.0]),
            add(c, [0.0, 1.0, 0.0]),
        ));
        q.add(&Quadric::from_triangle(
            c,
            add(c, [0.0, 1.0, 0.0]),
            add(c, [0.0, 0.0, 1.0]),
        ));
        q.add(&Quadric::from_triangle(
            c,
            add(c, [0.0, 0.0, 1.0]),
            add(c, [1.0, 0.0, 0.0]),
        ));
        let v = q.minimizer_near([0.0, 0.0, 0.0]);
        for k in 0..3 {
            assert!((v[k] - c[k]).abs() < 1e-9, "{v:?}");
        }
        assert!(q.error(v).abs() < 1e-12);
    }

    #[test]
    fn flat_cluster_keeps_mean_within_the_plane() {
        let q = Quadric::from_triangle([0.0, 0.0, 5.0], [1.0, 0.0, 5.0], [0.0, 1.0, 5.0]);
        let v = q.minimizer_near([0.3, 0.4, 4.0]);
        assert!((v[0] - 0.3).abs() < 1e-12 && (v[1] - 0.4).abs() < 1e-12);
        assert!((v[2] - 5.0).abs() < 1e-12);
    }

    #[test]
    fn eigen_decomposition_reconstructs_matrix() {
        let upper = [4.0, 1.0, -2.0, 3.0, 0.5, 1.0];
        let (values, vectors) = symmetric_eigen(upper);
        let full = [[4.0, 1.0, -2.0], [1.0, 3.0, 0.5], [-2.0, 0.5, 1.0]];
        for k in 0..3 {
            let u = vectors[k];
            for i in 0..3 {
                let au: f64 = (0..3).map(|j| full[i][j] * u[j]).sum();
                assert!((au - values[k] * u[i]).abs() < 1e-9);
            }
        }
    }
}
