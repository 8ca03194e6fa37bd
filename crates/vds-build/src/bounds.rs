//! Bounding volumes per node: axis-aligned boxes (build-time only), bounding spheres of the
//! supported triangles (Luebke & Erikson §4.2, the irrelevance and frustum tests) and cones of
//! normals (§3.2, silhouette and backface tests).
//!
//! Everything is computed in `f64` and rounded outwards when stored as `f32`, so stored bounds
//! stay conservative.
//!
//! Angles use the `libm` crate's `acos`, `atan2` and `sincos` rather than the platform's: the
//! system library picks an implementation by CPU at run time (glibc has FMA and non-FMA
//! versions, which may round differently), so the same input could give different `.vdt`
//! bytes on two machines. `libm` is plain Rust arithmetic, the same everywhere.

use crate::quadric::{cross, dot, sub};

/// An axis-aligned box of input positions; empty when `min > max`. Stored in `f32`: it only
/// ever holds input coordinates, whose minima and maxima are exact in `f32`, and the build
/// keeps one per node of two tree levels at once, so half the bytes matter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: [f32; 3],
    /// Upper corner.
    pub max: [f32; 3],
}

impl Aabb {
    /// The empty box.
    pub const EMPTY: Aabb = Aabb {
        min: [f32::INFINITY; 3],
        max: [f32::NEG_INFINITY; 3],
    };

    /// Grows the box to contain `p` (finite, as every imported position is).
    pub fn add_point(&mut self, p: [f32; 3]) {
        for k in 0..3 {
            self.min[k] = lesser(self.min[k], p[k]);
            self.max[k] = greater(self.max[k], p[k]);
        }
    }

    /// Grows the box to contain `other`.
    pub fn add_box(&mut self, other: &Aabb) {
        for k in 0..3 {
            self.min[k] = lesser(self.min[k], other.min[k]);
            self.max[k] = greater(self.max[k], other.max[k]);
        }
    }

    /// The centre (in `f64`, exactly the midpoint of the `f32` corners).
    pub fn center(&self) -> [f64; 3] {
        [0, 1, 2].map(|k| 0.5 * (f64::from(self.min[k]) + f64::from(self.max[k])))
    }

    /// The nearest point of the box to `p`.
    pub fn clamp(&self, p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| p[k].clamp(f64::from(self.min[k]), f64::from(self.max[k])))
    }
}

/// The smaller of two values that are not NaN (positions are finite: the importer refuses
/// others). One `minss` where `f32::min`, which must return the other operand of a NaN, takes
/// four instructions; the box updates of every incident triangle's corners made that a
/// tenth of a build's instructions.
#[inline]
fn lesser(a: f32, b: f32) -> f32 {
    if b < a { b } else { a }
}

/// The larger of two values that are not NaN (see [`lesser`]).
#[inline]
fn greater(a: f32, b: f32) -> f32 {
    if b > a { b } else { a }
}

/// A cone of normals: every bounded normal `n` satisfies `angle(axis, n) <= half_angle`.
///
/// The same type serves as a *two-sided* cone, which bounds normals up to sign: every `n`
/// has `n` or `−n` within `half_angle` of `axis` ([`NormalCone::fit_two_sided`],
/// [`NormalCone::merge_two_sided`]). CAD parts are thin shells: a cluster spanning both faces
/// of a plate or a pipe wall has normals on both sides, so any one-sided cone around them is
/// wider than a hemisphere and makes the node look like a silhouette from every view, while a
/// two-sided cone around them is narrow.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalCone {
    /// Unit axis.
    pub axis: [f64; 3],
    /// Half opening angle in radians, in `[0, π]`; negative for the empty cone.
    pub half_angle: f64,
}

/// Added to merged and fitted cone angles so rounding never leaves a normal just outside.
const CONE_SLACK_RADIANS: f64 = 1e-6;

impl NormalCone {
    /// The cone that bounds no normal (a cluster with only zero-area triangles).
    pub const EMPTY: NormalCone = NormalCone {
        axis: [0.0, 0.0, 1.0],
        half_angle: -1.0,
    };

    /// True when the cone bounds no normal.
    pub fn is_empty(&self) -> bool {
        self.half_angle < 0.0
    }

    /// The tightest cone around `normals` (unit vectors) with their normalised sum as axis.
    pub fn fit(normals: &[[f64; 3]]) -> NormalCone {
        NormalCone::fit_oriented(normals, |n| n)
    }

    /// A two-sided cone around `normals`: each normal is flipped into the hemisphere of the
    /// first one, and the one-sided cone of the result is fitted.
    pub fn fit_two_sided(normals: &[[f64; 3]]) -> NormalCone {
        let Some(&reference) = normals.first() else {
            return NormalCone::EMPTY;
        };
        NormalCone::fit_oriented(normals, |n| {
            if dot(n, reference) < 0.0 {
                n.map(|c| -c)
            } else {
                n
            }
        })
    }

    /// [`NormalCone::fit`] of `normals` each seen through `orient`. Plain loops over a slice
    /// and a comparison for the least cosine (the cosines of unit vectors are never NaN, so
    /// `f64::min`'s NaN rule is not needed): the build fits a cone for each of millions of
    /// leaves, and iterator adapters here cost more than the arithmetic.
    fn fit_oriented(normals: &[[f64; 3]], orient: impl Fn([f64; 3]) -> [f64; 3]) -> NormalCone {
        let Some(&first) = normals.first() else {
            return NormalCone::EMPTY;
        };
        let mut sum = [0.0; 3];
        for &n in normals {
            let n = orient(n);
            for k in 0..3 {
                sum[k] += n[k];
            }
        }
        let length = dot(sum, sum).sqrt();
        let axis = if length > 1e-9 {
            sum.map(|c| c / length)
        } else {
            orient(first)
        };
        // One acos for the widest normal instead of an angle per normal; acos is accurate
        // to ~1e-8 rad near 0, well inside the slack added below.
        let mut min_cos = 1.0f64;
        for &n in normals {
            let cos = dot(axis, orient(n));
            if cos < min_cos {
                min_cos = cos;
            }
        }
        // All normals along the axis (flat regions of CAD models, often exactly): acos(1) is
        // exactly 0, without the call.
        let half_angle = if min_cos >= 1.0 {
            0.0
        } else {
            libm::acos(min_cos.clamp(-1.0, 1.0))
        };
        NormalCone {
            axis,
            half_angle: (half_angle + CONE_SLACK_RADIANS).min(std::f64::consts::PI),
        }
    }

    /// The two-sided cone containing two two-sided cones: `other`'s axis, which stands for
    /// itself and its opposite, is taken on `self`'s side before the one-sided merge.
    // Inlined into the build's wide kernels (`crate::isa`), which would call a baseline
    // copy otherwise.
    #[inline(always)]
    pub fn merge_two_sided(&self, other: &NormalCone) -> NormalCone {
        if !self.is_empty() && !other.is_empty() && dot(self.axis, other.axis) < 0.0 {
            return self.merge(&NormalCone {
                axis: other.axis.map(|c| -c),
                half_angle: other.half_angle,
            });
        }
        self.merge(other)
    }

    /// The smallest cone containing both cones (as an axis rotation in their common plane).
    #[inline(always)]
    pub fn merge(&self, other: &NormalCone) -> NormalCone {
        if other.is_empty() {
            return *self;
        }
        if self.is_empty() {
            return *other;
        }
        // `angle_between`, its parts kept: the sine and cosine also decide most containments
        // without the arc tangent.
        let normal = cross(self.axis, other.axis);
        let sin_between = dot(normal, normal).sqrt();
        let cos_between = dot(self.axis, other.axis);
        if self.surely_contains(other, sin_between, cos_between) {
            return *self;
        }
        let between = libm::atan2(sin_between, cos_between);
        if between + other.half_angle <= self.half_angle {
            return *self;
        }
        if between + self.half_angle <= other.half_angle {
            return *other;
        }
        let half_angle = 0.5 * (self.half_angle + other.half_angle + between) + CONE_SLACK_RADIANS;
        if half_angle >= std::f64::consts::PI {
            return NormalCone {
                axis: self.axis,
                half_angle: std::f64::consts::PI,
            };
        }
        // Rotate self.axis towards other.axis by (half_angle - self.half_angle).
        let rotate_by = half_angle - self.half_angle;
        if sin_between < 1e-12 {
            // Axes (anti)parallel: containment failed above only if they are opposite.
            return NormalCone {
                axis: self.axis,
                half_angle: std::f64::consts::PI,
            };
        }
        // Unit vector in the plane of both axes, perpendicular to self.axis, towards other.
        let towards = cross(normal, self.axis).map(|c| c / sin_between);
        let (s, c) = libm::sincos(rotate_by);
        let axis = [0, 1, 2].map(|k| c * self.axis[k] + s * towards[k]);
        let length = dot(axis, axis).sqrt();
        NormalCone {
            axis: axis.map(|x| x / length),
            half_angle,
        }
    }

    /// True only where [`NormalCone::merge`]'s first test, `between + other.half_angle <=
    /// self.half_angle` with `between` the arc tangent of `sin_between / cos_between`, holds
    /// too, so that skipping the arc tangent there changes no result. Parallel axes (exact
    /// in CAD models, whose faces are often axis-aligned) give an arc tangent of exactly zero.
    /// Otherwise, for an acute angle `θ ≤ tan θ`, so `between` is at most `sin / cos` plus the
    /// arc tangent's rounding (under an ulp); the relative margin of 10⁻¹² covers that and
    /// the rounding of the sums several thousand times over.
    fn surely_contains(&self, other: &NormalCone, sin_between: f64, cos_between: f64) -> bool {
        if cos_between <= 0.0 {
            return false;
        }
        if sin_between == 0.0 {
            // Parallel axes: the arc tangent is exactly zero, and so is the test's rounding.
            return other.half_angle <= self.half_angle;
        }
        (sin_between / cos_between + other.half_angle) * (1.0 + 1e-12) <= self.half_angle
    }

    /// True when `n` (unit) lies in the cone, with `tolerance` radians of slack.
    pub fn contains(&self, n: [f64; 3], tolerance: f64) -> bool {
        !self.is_empty() && angle_between(self.axis, n) <= self.half_angle + tolerance
    }

    /// True when `n` or `−n` lies in the cone (the test of a two-sided cone).
    pub fn contains_either_way(&self, n: [f64; 3], tolerance: f64) -> bool {
        self.contains(n, tolerance) || self.contains(n.map(|c| -c), tolerance)
    }
}

/// The angle between two unit vectors, robust near 0 and π (atan2 of sine and cosine).
pub fn angle_between(a: [f64; 3], b: [f64; 3]) -> f64 {
    let c = cross(a, b);
    libm::atan2(dot(c, c).sqrt(), dot(a, b))
}

/// A triangle's unit normal, or `None` when its area is zero.
pub fn triangle_normal(p0: [f64; 3], p1: [f64; 3], p2: [f64; 3]) -> Option<[f64; 3]> {
    let n = cross(sub(p1, p0), sub(p2, p0));
    let length = dot(n, n).sqrt();
    (length > 0.0 && length.is_finite()).then(|| n.map(|c| c / length))
}

/// The smallest `f32` not below `x`, so a stored radius never shrinks.
pub fn round_up_f32(x: f64) -> f32 {
    let y = x as f32;
    if f64::from(y) < x { y.next_up() } else { y }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merged_cone_contains_both_inputs() {
        let a = NormalCone::fit(&[[1.0, 0.0, 0.0]]);
        let b = NormalCone::fit(&[[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        let m = a.merge(&b);
        for n in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] {
            assert!(m.contains(n, 1e-9), "{m:?} misses {n:?}");
        }
        assert!(m.half_angle < std::f64::consts::PI);
    }

    #[test]
    fn opposite_normals_give_full_cone() {
        let a = NormalCone::fit(&[[0.0, 0.0, 1.0]]);
        let b = NormalCone::fit(&[[0.0, 0.0, -1.0]]);
        let m = a.merge(&b);
        assert!(m.contains([0.0, 0.0, -1.0], 0.0) && m.contains([0.0, 0.0, 1.0], 0.0));
    }

    #[test]
    fn two_sided_cones_of_opposite_faces_are_narrow() {
        let plate = [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [0.0, 0.1f64.sin(), -(0.1f64.cos())],
        ];
        let one_sided = NormalCone::fit(&plate);
        let two_sided = NormalCone::fit_two_sided(&plate);
        assert!(one_sided.half_angle > 3.0);
        assert!(two_sided.half_angle < 0.11, "{two_sided:?}");
        let other = NormalCone::fit_two_sided(&[[0.0, 0.1, -1.0]]);
        let merged = two_sided.merge_two_sided(&other);
        for n in plate.into_iter().chain([[0.0, 0.1, -1.0]]) {
            let length = dot(n, n).sqrt();
            assert!(merged.contains_either_way(n.map(|c| c / length), 1e-9));
        }
        assert!(merged.half_angle < 0.2, "{merged:?}");
    }

    #[test]
    fn the_containment_shortcut_agrees_with_the_arc_tangent_test() {
        let mut seed = 0x2545_F491_4F6C_DD1Du64;
        let mut random = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut shortcuts = 0;
        for k in 0..200_000 {
            let a = NormalCone::fit(&[[0.0, 0.0, 1.0]]).axis;
            // Axes from exactly parallel to a quarter turn away.
            let tilt = if k % 4 == 0 {
                0.0
            } else {
                random() * random() * 1.5
            };
            let b = [tilt.sin(), 0.0, tilt.cos()];
            let other = NormalCone {
                axis: b,
                half_angle: random() * 0.5,
            };
            // Half-angles around the containment boundary, some exactly on it.
            let between = angle_between(a, b);
            let boundary = between + other.half_angle;
            let half_angle = match k % 3 {
                0 => boundary,
                1 => boundary * (1.0 + (random() - 0.5) * 1e-9),
                _ => boundary + (random() - 0.5) * 0.2,
            };
            let cone = NormalCone {
                axis: a,
                half_angle,
            };
            let normal = cross(a, b);
            let (sin, cos) = (dot(normal, normal).sqrt(), dot(a, b));
            if cone.surely_contains(&other, sin, cos) {
                shortcuts += 1;
                assert!(
                    between + other.half_angle <= half_angle,
                    "{cone:?} {other:?}"
                );
            }
        }
        assert!(
            shortcuts > 50_000,
            "the shortcut should decide many cases: {shortcuts}"
        );
    }

    #[test]
    fn round_up_never_shrinks() {
        for x in [0.1f64, 1.0 / 3.0, 1e-30, 12_345.678_901_234] {
            assert!(f64::from(round_up_f32(x)) >= x);
        }
    }
}
