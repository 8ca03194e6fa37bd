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
    ///
    /// Where the characteristic polynomial shows every eigenvalue of `A` above the cutoff,
    /// the truncated pseudo-inverse is the inverse, solved by cofactors; where it shows
    /// exactly one under it (a crease or a cylinder-like patch, free along its axis), that
    /// eigenvalue and its eigenvector are found directly and the rest solved by cofactors
    /// (`solve_directly`). Only the other clusters (flat ones, whose planes constrain one
    /// direction, and degenerate ones) pay for the Jacobi eigen-decomposition, which costs a
    /// few hundred nanoseconds.
    // Inlined into the build's wide kernels (`crate::isa`), as is `symmetric_eigen`.
    #[inline(always)]
    pub fn minimizer_near(&self, mean: [f64; 3]) -> [f64; 3] {
        // Gradient of E at the mean is 2(A·mean + b); step = -A⁺(A·mean + b).
        let residual = add(self.apply(mean), self.b);
        match solve_directly(&self.a, residual) {
            Some(pseudo_inverse_times_residual) => sub(mean, pseudo_inverse_times_residual),
            None => self.minimizer_by_eigen(mean, residual),
        }
    }

    /// [`Quadric::minimizer_near`] through the eigen-decomposition, for any `A`; `residual`
    /// is `A·mean + b`.
    #[inline(always)]
    fn minimizer_by_eigen(&self, mean: [f64; 3], residual: [f64; 3]) -> [f64; 3] {
        let (values, vectors) = symmetric_eigen(self.a);
        let largest = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if largest <= 0.0 || !largest.is_finite() {
            return mean;
        }
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

/// `A⁺·r` by [`solve_well_conditioned`] or [`solve_one_dropped`], where either applies, or
/// `None` (the eigen-decomposition decides then). Both run on `A` and `r` scaled by the power
/// of two that brings the trace into `[1, 2)`: the scaling is exact and `(sA)⁺·(s·r) = A⁺·r`,
/// so the result is the same bits as unscaled wherever that stays in range, and determinants
/// and cross products of quadrics of any size (areas of 10⁻⁸⁰ or 10¹⁰⁰) stay normal
/// numbers instead of overflowing or losing their precision in subnormals. A result that is
/// still not finite (a residual too large for its scale) is left to the eigen-decomposition.
#[inline(always)]
fn solve_directly(a: &[f64; 6], r: [f64; 3]) -> Option<[f64; 3]> {
    let scale = inverse_power_of_two(a[0] + a[3] + a[5])?;
    let a = a.map(|x| x * scale);
    let r = r.map(|x| x * scale);
    let c = characteristic(&a);
    let solved = solve_well_conditioned(&c, r).or_else(|| solve_one_dropped(&a, &c, r))?;
    solved.iter().all(|x| x.is_finite()).then_some(solved)
}

/// `2⁻ᵉ` for a positive normal `x` in `[2ᵉ, 2ᵉ⁺¹)`, where that is a normal number too;
/// `None` otherwise.
#[inline(always)]
fn inverse_power_of_two(x: f64) -> Option<f64> {
    if !(x.is_normal() && x > 0.0) {
        return None;
    }
    // Biased exponents: `e + 1023` for `x`, `−e + 1023 = 2046 − (e + 1023)` for its inverse.
    let biased = (x.to_bits() >> 52) & 0x7ff;
    let inverse = 2046 - biased;
    (inverse >= 1).then(|| f64::from_bits(inverse << 52))
}

/// The coefficients of the characteristic polynomial `λ³ − trace·λ² + minors·λ − det` of a
/// symmetric 3×3 matrix (upper triangle), and its cofactor matrix (upper triangle, which is
/// `det · A⁻¹`).
struct Characteristic {
    trace: f64,
    minors: f64,
    det: f64,
    cofactors: [f64; 6],
}

#[inline(always)]
fn characteristic(a: &[f64; 6]) -> Characteristic {
    let [xx, xy, xz, yy, yz, zz] = *a;
    let cofactors = [
        yy * zz - yz * yz,
        xz * yz - xy * zz,
        xy * yz - xz * yy,
        xx * zz - xz * xz,
        xy * xz - xx * yz,
        xx * yy - xy * xy,
    ];
    Characteristic {
        trace: xx + yy + zz,
        minors: cofactors[0] + cofactors[3] + cofactors[5],
        det: xx * cofactors[0] + xy * cofactors[1] + xz * cofactors[2],
        cofactors,
    }
}

/// Whether every eigenvalue of the symmetric matrix with this characteristic polynomial
/// exceeds the cutoff times the largest, shown without the eigenvalues (a `false` only means
/// "not shown"). For a positive semi-definite matrix (a quadric's `A`, up to rounding) with
/// eigenvalues `λ₁ ≤ λ₂ ≤ λ₃`, take `x` = a little over the cutoff times the trace, which is at
/// least `λ₃`:
/// - `minors = λ₁λ₂ + λ₁λ₃ + λ₂λ₃ ≤ 3·λ₂·λ₃ ≤ 3·λ₂·trace`, so `minors > 3·trace·x` shows
///   `λ₂ > x`;
/// - with `λ₂, λ₃ > x`, the polynomial `p(x) = (x − λ₁)(x − λ₂)(x − λ₃)` is negative exactly
///   when `x < λ₁`.
///
/// The margin of 1 % in `x` keeps the decision clear of rounding: near the cutoff `p(x)`
/// is about `(x − λ₁)·λ₂·λ₃`, far above the rounding of its terms, and a matrix this test
/// passes has no eigenvalue within 1 % of the cutoff, where the eigen-decomposition's own
/// rounding could decide otherwise. Non-finite input fails every comparison.
#[inline(always)]
fn all_directions_kept(c: &Characteristic) -> bool {
    let x = kept_bound(c);
    let p = ((x - c.trace) * x + c.minors) * x - c.det;
    middle_kept(c) && p < 0.0
}

/// A little over the cutoff times the trace, so at least the cutoff times the largest
/// eigenvalue of a positive semi-definite matrix: the bound [`all_directions_kept`] and
/// [`solve_one_dropped`] show eigenvalues to clear.
#[inline(always)]
fn kept_bound(c: &Characteristic) -> f64 {
    1.01 * RELATIVE_EIGEN_CUTOFF * c.trace
}

/// Whether the middle eigenvalue provably exceeds [`kept_bound`]: `minors ≤ 3·λ₂·trace`
/// (see [`all_directions_kept`]). Non-finite input fails.
#[inline(always)]
fn middle_kept(c: &Characteristic) -> bool {
    let x = kept_bound(c);
    x > 0.0 && x.is_finite() && c.minors > 3.0 * c.trace * x
}

/// `A⁻¹·r` by cofactors where [`all_directions_kept`] shows that the rank-truncated
/// pseudo-inverse is the inverse (eigenvalues above a thousandth of the largest, so the
/// inverse is well conditioned); `None` otherwise.
#[inline(always)]
fn solve_well_conditioned(c: &Characteristic, r: [f64; 3]) -> Option<[f64; 3]> {
    if !all_directions_kept(c) {
        return None;
    }
    Some(cofactor_solve(c, r))
}

/// `A⁻¹·r` from `A`'s cofactors and determinant.
#[inline(always)]
fn cofactor_solve(c: &Characteristic, r: [f64; 3]) -> [f64; 3] {
    let [m00, m01, m02, m11, m12, m22] = c.cofactors;
    let inverse_det = 1.0 / c.det;
    [
        (m00 * r[0] + m01 * r[1] + m02 * r[2]) * inverse_det,
        (m01 * r[0] + m11 * r[1] + m12 * r[2]) * inverse_det,
        (m02 * r[0] + m12 * r[1] + m22 * r[2]) * inverse_det,
    ]
}

/// `A⁺·r` where exactly one eigenvalue of `A` (positive semi-definite, with characteristic
/// `c`) provably falls under the cutoff and the other two clear it, each by 1 %: a crease or
/// a cylinder-like patch, whose proxy keeps the mean's place along the axis the planes leave
/// free. `None` where that is not shown (the eigen-decomposition decides then).
///
/// The middle eigenvalue is shown to clear the cutoff as in [`all_directions_kept`]. The
/// smallest, `λ₁`, is the smallest root of the characteristic polynomial, found by Newton's
/// method from 0: the polynomial is concave and increasing left of `λ₁` (which is at most a
/// third of the trace), so every step lands left of the root and the iterates rise to it;
/// one that has not settled within eight steps leaves the solve to the eigen-decomposition.
/// The other two follow from the trace and the minors (`λ₂ + λ₃ = trace − λ₁`,
/// `λ₂·λ₃ = minors − λ₁·(λ₂ + λ₃)`). Its eigenvector `u₁` is the longest cross product of
/// two rows of `A − λ₁·I`, whose rows span the plane of the other two. With `B` the part
/// of `A` kept, `B⁺·r = M⁻¹·r − u₁(u₁·r)/λ₃` for `M = A + (λ₃ − λ₁)·u₁u₁ᵀ` (eigenvalues
/// `λ₃, λ₂, λ₃`, well conditioned), solved by cofactors.
#[inline(always)]
fn solve_one_dropped(a: &[f64; 6], c: &Characteristic, r: [f64; 3]) -> Option<[f64; 3]> {
    // `λ₂` clearing the cutoff also keeps `λ₁` a simple root well apart from `λ₂`, where
    // Newton's method converges in a few steps.
    if !middle_kept(c) {
        return None;
    }
    let (trace, minors, det) = (c.trace, c.minors, c.det);
    let mut smallest = 0.0f64;
    let mut converged = false;
    for _ in 0..8 {
        let value = ((smallest - trace) * smallest + minors) * smallest - det;
        let slope = (3.0 * smallest - 2.0 * trace) * smallest + minors;
        let step = value / slope;
        smallest -= step;
        if step.abs() <= 1e-17 * trace {
            converged = true;
            break;
        }
    }
    if !converged {
        return None;
    }
    let others_sum = trace - smallest;
    let others_product = minors - smallest * others_sum;
    let discriminant = (others_sum * others_sum - 4.0 * others_product).max(0.0);
    let largest = 0.5 * (others_sum + discriminant.sqrt());
    let middle = others_product / largest;
    let cut = RELATIVE_EIGEN_CUTOFF * largest;
    if !(largest.is_finite() && smallest < 0.99 * cut && middle > 1.01 * cut) {
        return None;
    }
    let [xx, xy, xz, yy, yz, zz] = *a;
    let rows = [
        [xx - smallest, xy, xz],
        [xy, yy - smallest, yz],
        [xz, yz, zz - smallest],
    ];
    let mut normal = [0.0; 3];
    let mut longest = 0.0;
    for (i, j) in [(0, 1), (0, 2), (1, 2)] {
        let candidate = cross(rows[i], rows[j]);
        let length = dot(candidate, candidate);
        if length > longest {
            (normal, longest) = (candidate, length);
        }
    }
    if !(longest > 0.0 && longest.is_finite()) {
        return None;
    }
    let u = normal.map(|x| x / longest.sqrt());
    let lift = largest - smallest;
    let m = [
        xx + lift * u[0] * u[0],
        xy + lift * u[0] * u[1],
        xz + lift * u[0] * u[2],
        yy + lift * u[1] * u[1],
        yz + lift * u[1] * u[2],
        zz + lift * u[2] * u[2],
    ];
    let solved = cofactor_solve(&characteristic(&m), r);
    let along = dot(u, r) / largest;
    Some([0, 1, 2].map(|k| solved[k] - along * u[k]))
}

/// Eigenvalues and unit eigenvectors of a symmetric 3×3 matrix (upper triangle
/// `xx, xy, xz, yy, yz, zz`), by cyclic Jacobi rotations.
///
/// Each rotation updates the six distinct entries only and sets the one it annihilates to
/// zero (Rutishauser's form, as in Numerical Recipes §11.1), instead of rotating the full
/// matrix's rows and columns.
#[inline(always)]
pub fn symmetric_eigen(upper: [f64; 6]) -> ([f64; 3], [[f64; 3]; 3]) {
    let [xx, xy, xz, yy, yz, zz] = upper;
    // `d` the diagonal; `off[k]` the entry off it opposite index k: (1,2), (0,2), (0,1).
    let mut d = [xx, yy, zz];
    let mut off = [yz, xz, xy];
    // Columns of `v` are the eigenvectors.
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    // Jacobi converges quadratically; 8 sweeps reach f64 precision for any 3×3 input.
    for _sweep in 0..8 {
        let sum_off = off[0].abs() + off[1].abs() + off[2].abs();
        let scale = d[0].abs() + d[1].abs() + d[2].abs();
        if sum_off <= 1e-15 * scale || sum_off == 0.0 {
            break;
        }
        // Pairs (p, q) with r the third index: (0, 1), (0, 2), (1, 2).
        for (p, q, r) in [(0usize, 1usize, 2usize), (0, 2, 1), (1, 2, 0)] {
            let apq = off[r];
            if apq == 0.0 {
                continue;
            }
            let theta = (d[q] - d[p]) / (2.0 * apq);
            // The smaller root of t² + 2tθ − 1 = 0 (a rotation of at most 45°); for θ = 0,
            // t = 1.
            let root = (theta * theta + 1.0).sqrt();
            let t = if theta >= 0.0 {
                1.0 / (theta + root)
            } else {
                -1.0 / (root - theta)
            };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            d[p] -= t * apq;
            d[q] += t * apq;
            off[r] = 0.0;
            // The entries (r, p) and (r, q), stored opposite q and p.
            let (arp, arq) = (off[q], off[p]);
            off[q] = c * arp - s * arq;
            off[p] = s * arp + c * arq;
            for row in v.iter_mut() {
                let (x, y) = (row[p], row[q]);
                row[p] = c * x - s * y;
                row[q] = s * x + c * y;
            }
        }
    }
    let vectors = [
        [v[0][0], v[1][0], v[2][0]],
        [v[0][1], v[1][1], v[2][1]],
        [v[0][2], v[1][2], v[2][2]],
    ];
    (d, vectors)
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

    /// A cluster's quadric: `planes` area-weighted planes through points of a unit box around
    /// `center`, with normals spread by `spread` around the z axis, as much along x as along
    /// y (0: a flat cluster; 1: normals in every direction), from `seed`.
    fn cluster_quadric(seed: u64, planes: usize, spread: f64, center: [f64; 3]) -> Quadric {
        cluster_quadric_spread(seed, planes, [spread, spread], center)
    }

    /// [`cluster_quadric`] with the normals spread by `spread[0]` along x and `spread[1]`
    /// along y (a cylinder-like patch where one is large and the other small).
    fn cluster_quadric_spread(
        seed: u64,
        planes: usize,
        spread: [f64; 2],
        center: [f64; 3],
    ) -> Quadric {
        let mut state = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut q = Quadric::default();
        for _ in 0..planes {
            let n = [spread[0] * next(), spread[1] * next(), 1.0 + 0.1 * next()];
            let length = dot(n, n).sqrt();
            let point = [center[0] + next(), center[1] + next(), center[2] + next()];
            q.add(&Quadric::from_plane(
                n.map(|c| c / length),
                point,
                0.5 + next().abs(),
            ));
        }
        q
    }

    #[test]
    fn direct_solves_agree_with_the_eigen_decomposition() {
        // Spreads from flat (two eigenvalues under the cutoff: only the eigen path solves
        // those) through patches curved one way (one under: the one-dropped solve) and the
        // cutoff's neighbourhood to fully three-dimensional clusters (the cofactor solve).
        let spreads = [
            [0.0, 0.0],
            [1e-3, 1e-3],
            [0.01, 0.01],
            [0.03, 0.03],
            [0.05, 0.05],
            [0.1, 0.1],
            [1.0, 1.0],
            [1.0, 0.0],
            [1.0, 1e-3],
            [0.5, 0.01],
            [0.3, 0.02],
            [0.2, 0.03],
            [2.0, 0.05],
        ];
        let (mut all_kept, mut one_dropped, mut by_eigen) = (0, 0, 0);
        for seed in 0..4_000u64 {
            let spread = spreads[seed as usize % spreads.len()];
            let center = [1e3 * (seed % 7) as f64, -50.0, 3.0];
            let q = cluster_quadric_spread(seed, 2 + seed as usize % 9, spread, center);
            let mean = [center[0] + 0.25, center[1] - 0.5, center[2] + 0.1];
            let residual = add(q.apply(mean), q.b);
            let reference = q.minimizer_by_eigen(mean, residual);
            let c = characteristic(&q.a);
            if solve_well_conditioned(&c, residual).is_some() {
                all_kept += 1;
            } else if solve_one_dropped(&q.a, &c, residual).is_some() {
                one_dropped += 1;
            } else {
                by_eigen += 1;
            }
            let point = q.minimizer_near(mean);
            let moved = dot(sub(reference, mean), sub(reference, mean)).sqrt();
            let apart = dot(sub(point, reference), sub(point, reference)).sqrt();
            assert!(
                apart <= 1e-9 * (1.0 + moved),
                "seed {seed}: {point:?} against {reference:?}"
            );
        }
        // Every path is exercised, so the comparison tests the direct ones.
        assert!(
            all_kept > 300 && one_dropped > 300 && by_eigen > 300,
            "{all_kept} all kept, {one_dropped} one dropped, {by_eigen} by eigen"
        );
    }

    #[test]
    fn rank_one_quadrics_with_rounding_noise_are_left_to_the_eigen_path() {
        // A quadric of one plane's triangles summed in another order (from a property test):
        // rank one up to rounding, so its minors and determinant are noise, on which Newton's
        // method once wandered to a wrong "smallest eigenvalue" and a NaN proxy.
        let q = Quadric {
            a: [
                11.812107967452596,
                -1.2672608761542725,
                25.313898041852887,
                0.13595796217376047,
                -2.715799135919738,
                54.24886361003329,
            ],
            b: [1.0, -2.0, 0.5],
            c: 0.0,
        };
        let mean = [0.3, 0.1, -0.2];
        let residual = add(q.apply(mean), q.b);
        let c = characteristic(&q.a);
        assert!(solve_well_conditioned(&c, residual).is_none());
        assert!(solve_one_dropped(&q.a, &c, residual).is_none());
        let point = q.minimizer_near(mean);
        assert!(point.iter().all(|x| x.is_finite()));
        assert_eq!(point, q.minimizer_by_eigen(mean, residual));
    }

    #[test]
    fn direct_solves_hold_at_extreme_scales() {
        // Quadrics of areas far outside any mesh's (from an independent review): unscaled,
        // the determinant overflowed or went subnormal (NaN or infinite proxies), and a
        // subnormal cross product gave an eigenvector that was not of unit length.
        let mut cases = Vec::new();
        for scale in [1e103, 1e-104, 1e300, 1e-300, 6.6e102, 2e-108] {
            cases.push((
                Quadric {
                    a: [1.0, 0.3, -0.2, 0.8, 0.1, 0.5].map(|x| x * scale),
                    b: [0.0; 3],
                    c: 0.0,
                },
                [1.0, -2.0, 0.5],
            ));
        }
        for scale in [1.2882495516931323e-80, 1e-200, 1e200] {
            cases.push((
                Quadric {
                    a: [1.0, 0.0, 0.0, 0.01, 0.0, 0.0005].map(|x| x * scale),
                    b: [0.0, 0.0, -0.05 * scale],
                    c: 0.0,
                },
                [1.0, 1.0, 1.0],
            ));
        }
        for (q, mean) in cases {
            let residual = add(q.apply(mean), q.b);
            let reference = q.minimizer_by_eigen(mean, residual);
            let point = q.minimizer_near(mean);
            assert!(point.iter().all(|x| x.is_finite()), "{q:?}: {point:?}");
            let apart = dot(sub(point, reference), sub(point, reference)).sqrt();
            assert!(apart <= 1e-9, "{q:?}: {point:?} against {reference:?}");
        }
    }

    #[test]
    fn creases_along_each_axis_agree_with_the_eigen_decomposition() {
        // Normals in a plane through one axis (a crease or cylinder along it): one eigenvalue
        // is zero, its eigenvector the axis, and the rows of `A − λ₁I` that give it differ
        // with the axis.
        for axis in 0..3 {
            let mut q = Quadric::default();
            for k in 0..6 {
                let angle = 0.3 * k as f64;
                let mut n = [0.0; 3];
                n[(axis + 1) % 3] = angle.cos();
                n[(axis + 2) % 3] = angle.sin();
                q.add(&Quadric::from_plane(
                    n,
                    [0.1 * k as f64, 0.2, -0.3],
                    1.0 + k as f64,
                ));
            }
            let mean = [0.5, -0.25, 2.0];
            let residual = add(q.apply(mean), q.b);
            let c = characteristic(&q.a);
            assert!(
                solve_one_dropped(&q.a, &c, residual).is_some(),
                "axis {axis}"
            );
            let reference = q.minimizer_by_eigen(mean, residual);
            let point = q.minimizer_near(mean);
            let apart = dot(sub(point, reference), sub(point, reference)).sqrt();
            assert!(
                apart <= 1e-9,
                "axis {axis}: {point:?} against {reference:?}"
            );
            // Free along the axis: the mean's coordinate is kept.
            assert!(
                (point[axis] - mean[axis]).abs() <= 1e-9,
                "axis {axis}: {point:?}"
            );
        }
    }

    #[test]
    fn direct_solve_declines_below_the_cutoff() {
        // Eigenvalues 1, 1 and a third under, at and over the cutoff (a thousandth of the
        // largest), in a rotated frame: the direct solve must decline the first two (the
        // eigen path drops that direction) and take the third, which its bound (the cutoff
        // times the trace, 2) clears.
        let c = (0.6f64, 0.8f64);
        for (smallest, may_solve) in [(0.5e-3, false), (1e-3, false), (3e-3, true)] {
            let diagonal = [1.0, 1.0, smallest];
            // R·diag·Rᵀ for a rotation about x by the angle with cosine 0.6.
            let a = [
                diagonal[0],
                0.0,
                0.0,
                c.0 * c.0 * diagonal[1] + c.1 * c.1 * diagonal[2],
                c.0 * c.1 * (diagonal[2] - diagonal[1]),
                c.1 * c.1 * diagonal[1] + c.0 * c.0 * diagonal[2],
            ];
            let solved = solve_well_conditioned(&characteristic(&a), [1.0, 1.0, 1.0]).is_some();
            assert_eq!(solved, may_solve, "smallest eigenvalue {smallest}");
        }
    }

    #[test]
    fn eigen_decomposition_reconstructs_matrix() {
        let mut matrices = vec![
            [4.0, 1.0, -2.0, 3.0, 0.5, 1.0],
            // Rank one, a repeated eigenvalue, already diagonal, zero.
            [1.0, 2.0, 3.0, 4.0, 6.0, 9.0],
            [2.0, 1.0, 1.0, 2.0, 1.0, 2.0],
            [5.0, 0.0, 0.0, -1.0, 0.0, 2.0],
            [0.0; 6],
        ];
        matrices
            .extend((0..200).map(|seed| cluster_quadric(seed, 5, 0.01 * seed as f64, [0.0; 3]).a));
        for upper in matrices {
            let (values, vectors) = symmetric_eigen(upper);
            let full = [
                [upper[0], upper[1], upper[2]],
                [upper[1], upper[3], upper[4]],
                [upper[2], upper[4], upper[5]],
            ];
            let scale = upper.iter().fold(1.0f64, |m, x| m.max(x.abs()));
            for k in 0..3 {
                let u = vectors[k];
                for i in 0..3 {
                    let au: f64 = (0..3).map(|j| full[i][j] * u[j]).sum();
                    assert!((au - values[k] * u[i]).abs() < 1e-12 * scale, "{upper:?}");
                }
                for (l, w) in vectors.iter().enumerate() {
                    let expected = if l == k { 1.0 } else { 0.0 };
                    assert!((dot(u, *w) - expected).abs() < 1e-12, "{upper:?}");
                }
            }
        }
    }
}
