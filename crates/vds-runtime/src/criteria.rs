//! What decides a node's fate: the screen-space error bound, silhouettes, backfacing regions,
//! the view frustum and gaze (Luebke & Erikson 1997 §3, §4.2–4.3).
//!
//! ## The screen-space bound
//! Every original vertex `v` under a node lies within `r` (the node's error radius) of its
//! proxy `p`, so folding moves `v`'s image along the projection of a segment inside the ball
//! `B(p, r)`. For a pinhole with focal length `f` pixels, the image of a point `q` moves by at
//! most `f·‖dq‖·√(1 + ‖q_xy‖²/q_z²) / q_z` per unit of motion (the Jacobian of `q ↦ f·q_xy/q_z`
//! and Cauchy–Schwarz). Over the ball, `q_z ≥ d = p_z − r` and `‖q_xy‖ ≤ ρ + r` with
//! `ρ = ‖p_xy‖`, so the screen error is at most
//!
//! ```text
//! E = f·r·√(d² + (ρ + r)²) / d²      (camera coordinates, d > 0)
//! ```
//!
//! This is the paper's `r·cot(φ/2)/‖c − e‖` test made exact off-centre: on the view axis it is
//! `f·r/d`, and towards the frustum's edge it grows by the `1/cos θ` that the paper's form
//! misses. It is compared without division or square root of the whole, as in §4.3:
//! `E ≤ t ⟺ f²r²(d² + (ρ+r)²) ≤ t²d⁴`. Nodes whose ball reaches the eye plane (`d ≤ 0`)
//! have unbounded error and unfold.
//!
//! ## Cones (§3.2)
//! A node's normal cone (axis `a`, half-angle `α`) bounds the normals of every triangle
//! touching it; the viewing cone from the eye to its bounding sphere has half-angle
//! `β = asin(R/‖c − e‖)`. With `γ` the angle between `a` and `c − e`, every normal makes an
//! angle in `[γ−α−β, γ+α+β]` with every view ray into the sphere, so the node is entirely
//! backfacing when `γ + α + β < π/2`, entirely front-facing when `γ − α − β > π/2`, and may
//! hold silhouette edges otherwise.

use glam::Vec3;

use crate::store::{Hot, Tested};
use crate::view::{Camera, View};

/// How the cut is driven.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Goal {
    /// Unfold until no visible vertex is more than this far from its original image: pixels
    /// with a camera, scene units when view-independent.
    Threshold(f32),
    /// The best cut of at most this many triangles (§3.3).
    Budget(u32),
}

/// What nodes outside the view frustum do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrustumMode {
    /// No frustum test: off-screen regions keep full screen-space accuracy.
    Off,
    /// Nodes entirely outside fold (§4.2), so invisible regions cost almost no triangles.
    #[default]
    Fold,
    /// Nodes entirely outside are irrelevant: left as they are, neither folded nor unfolded,
    /// so turning away and back costs no work. Budget mode treats them as [`FrustumMode::Fold`].
    Ignore,
}

/// Gaze-directed simplification: the threshold is tightest along a focus direction and grows
/// towards the periphery.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gaze {
    /// Focus direction in world space (need not be unit length).
    pub direction: [f32; 3],
    /// The threshold is multiplied by `1 + falloff · θ`, `θ` the angle in radians between
    /// the focus direction and the nearest point of a node's bounding sphere.
    pub falloff: f32,
}

/// Every criterion of the cut besides its goal; all combine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Criteria {
    /// Nodes that may hold silhouette edges use the threshold times this factor (< 1 is
    /// tighter); `None` turns silhouette preservation off.
    pub silhouette_factor: Option<f32>,
    /// Fold nodes whose every triangle faces away from the eye.
    pub backface: bool,
    /// What nodes outside the frustum do.
    pub frustum: FrustumMode,
    /// Optional gaze-directed falloff.
    pub gaze: Option<Gaze>,
    /// Refuse folds that would flip the normal of a surviving triangle (mesh folding).
    pub prevent_mesh_folds: bool,
    /// Which error the budget mode ranks nodes by. The threshold mode always holds the
    /// vertex bound (the screen-space guarantee).
    pub bound: Bound,
}

/// The error a triangle budget spends its triangles against ([`Criteria::bound`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Bound {
    /// How far the surface moves when a node folds, as the builder's quadric measures it
    /// ([`crate::Node::surface_error`]): vertices sliding along a flat plate cost little, a
    /// fold that flattens a ridge or shrinks a thin part costs much. The node's own
    /// projected size still decides how near it is (its ball's distance from the eye), and a
    /// 1/32 share of the error radius is added, so that flat regions are refined by size.
    #[default]
    Surface,
    /// The error radius: the largest distance any vertex moves (the paper's measure, which
    /// the threshold mode guarantees).
    Vertex,
}

/// The share of the error radius added to the surface error when ranking by it: flat
/// regions (surface error near zero) are then refined largest first, and a node whose
/// vertices move far is not left folded for a small surface error alone. Chosen on
/// `vds-bench fidelity`: 1/1024 and 1/8 each made one of the bunny and AS1 rows worse.
const TIE_BREAK: f32 = 1.0 / 32.0;

impl Default for Criteria {
    fn default() -> Self {
        Criteria {
            silhouette_factor: Some(0.25),
            backface: true,
            frustum: FrustumMode::Fold,
            gaze: None,
            prevent_mesh_folds: false,
            bound: Bound::Surface,
        }
    }
}

/// Where the cut is seen from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Viewpoint {
    /// A camera: screen-space criteria.
    Camera(Camera),
    /// No camera: the object-space error radius alone decides (no culling, no cones), so a
    /// cut compares with ordinary simplifiers at equal triangle counts.
    Independent,
}

/// What the threshold test says about a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    /// Its error is too large: unfold it.
    Unfold,
    /// It may be folded.
    Fold,
    /// Leave it as it is (outside the frustum in [`FrustumMode::Ignore`]).
    Keep,
}

/// How a node's triangles face the eye.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Facing {
    /// Every triangle faces the eye (or the node bounds no normal).
    Front,
    /// Every triangle faces away.
    Back,
    /// Triangles face both ways but none edge-on: a thin shell (a two-sided cone) seen
    /// across its faces. Neither a silhouette nor foldable as backfacing.
    BothSides,
    /// Some may face either way: the node may hold silhouette edges.
    Silhouette,
}

/// The criteria evaluated for one viewpoint: built once per frame, asked once per node.
#[derive(Debug, Clone, Copy)]
pub struct Judge {
    view: Option<View>,
    criteria: Criteria,
    gaze_direction: Vec3,
    focal_sq: f32,
}

impl Judge {
    /// A judge for `viewpoint` under `criteria`.
    pub fn new(viewpoint: &Viewpoint, criteria: &Criteria) -> Judge {
        let view = match viewpoint {
            Viewpoint::Camera(camera) => Some(camera.view()),
            Viewpoint::Independent => None,
        };
        let gaze_direction = criteria
            .gaze
            .map(|g| Vec3::from(g.direction).normalize_or_zero())
            .unwrap_or(Vec3::ZERO);
        Judge {
            view,
            criteria: *criteria,
            gaze_direction,
            focal_sq: view.map_or(1.0, |v| v.focal_px * v.focal_px),
        }
    }

    /// The same judge for another view of the same camera.
    pub(crate) fn with_view(&self, view: View) -> Judge {
        Judge {
            view: Some(view),
            ..*self
        }
    }

    /// The prepared camera, if there is one.
    pub fn view(&self) -> Option<&View> {
        self.view.as_ref()
    }

    /// The criteria this judge applies.
    pub fn criteria(&self) -> &Criteria {
        &self.criteria
    }

    /// The tightest threshold any node can get from `t`: silhouettes scale it down, gaze
    /// only up.
    #[inline]
    pub fn tightest(&self, t: f32) -> f32 {
        match self.view {
            Some(_) => t * self.criteria.silhouette_factor.map_or(1.0, |s| s.min(1.0)),
            None => t,
        }
    }

    /// True when every child of the node with test data `hot` is certainly within `tight`
    /// ([`Judge::tightest`]): one bound for the whole group, from the ball around the node's
    /// proxy that holds every child's error ball (see [`Hot::group_radius`]). Each child's
    /// own bound has a ball inside it and an error radius no larger, and the bound grows with
    /// both, so it is no larger than this one.
    #[inline]
    pub fn group_within(&self, hot: &Hot, tight: f32) -> bool {
        self.group_test::<false>(hot, tight).is_some()
    }

    /// [`Judge::group_within`], and when the group passes, how far the node's proxy may move
    /// in camera coordinates before it could fail ([`crate::reuse`]; zero without a camera).
    #[inline]
    pub(crate) fn group_margin(&self, hot: &Hot, tight: f32) -> Option<f32> {
        self.group_test::<true>(hot, tight)
    }

    #[inline]
    fn group_test<const MARGIN: bool>(&self, hot: &Hot, tight: f32) -> Option<f32> {
        let Some(view) = &self.view else {
            return (hot.group_error <= tight).then_some(0.0);
        };
        let r = hot.group_error;
        if r == 0.0 {
            return Some(f32::INFINITY);
        }
        let c = view.to_camera(Vec3::from(hot.proxy));
        let d = c.z - hot.group_radius;
        if d <= 0.0 {
            return None;
        }
        let axis_distance = (c.x * c.x + c.y * c.y).sqrt();
        // In f64 for the same reason as in `decide_inner`: fourth powers of distances.
        let (r64, rho, d2, tight64) = (
            f64::from(r),
            f64::from(axis_distance + hot.group_radius),
            f64::from(d) * f64::from(d),
            f64::from(tight),
        );
        if f64::from(self.focal_sq) * r64 * r64 * (d2 + rho * rho) > tight64 * tight64 * d2 * d2 {
            return None;
        }
        Some(if MARGIN {
            crate::reuse::pass_margin(
                view.focal_px,
                r,
                c.z,
                axis_distance,
                hot.group_radius,
                tight,
            )
        } else {
            0.0
        })
    }

    /// How far from the eye the points a test of `hot`'s group depends on can be: its proxy's
    /// distance plus the group radius, with room for rounding.
    pub(crate) fn group_reach(&self, hot: &Hot) -> f32 {
        self.view.map_or(0.0, |view| {
            (Vec3::from(hot.proxy) - view.eye).length() * 1.0001 + hot.group_radius
        })
    }

    /// Whether node `n` should unfold under threshold `t` (pixels, or scene units when
    /// view-independent).
    #[inline]
    pub fn decide(&self, n: Tested<'_>, t: f32) -> Decision {
        self.decide_inner::<false>(n, t).0
    }

    /// [`Judge::decide`], and when the node folds by the screen-space test at the tightest
    /// threshold (so whatever its facing), how far its proxy may move in camera coordinates
    /// before that could change ([`crate::reuse`]); zero otherwise.
    #[inline(always)]
    pub(crate) fn decide_with_margin(&self, n: Tested<'_>, t: f32) -> (Decision, f32) {
        self.decide_inner::<true>(n, t)
    }

    #[inline]
    fn decide_inner<const MARGIN: bool>(&self, n: Tested<'_>, t: f32) -> (Decision, f32) {
        let Some(view) = &self.view else {
            let decision = if n.hot.error_radius > t {
                Decision::Unfold
            } else {
                Decision::Fold
            };
            return (decision, 0.0);
        };
        let ignore_outside = self.criteria.frustum == FrustumMode::Ignore;
        if ignore_outside && self.outside(view, n) {
            return (Decision::Keep, 0.0);
        }
        let r = n.hot.error_radius;
        if r == 0.0 {
            return (Decision::Fold, f32::INFINITY);
        }
        let c = view.to_camera(Vec3::from(n.hot.proxy));
        let d = c.z - r;
        // Cheapest first: most nodes of a settled cut are far below even the tightest limit.
        let (lhs, d4, axis_distance) = screen_test_sides(self.focal_sq, r, c);
        let tightest = f64::from(self.tightest(t));
        if lhs <= tightest * tightest * d4 {
            let margin = if MARGIN {
                crate::reuse::pass_margin(view.focal_px, r, c.z, axis_distance, r, tightest as f32)
            } else {
                0.0
            };
            return (Decision::Fold, margin);
        }
        (self.decide_rest(view, n, t, d, lhs, d4, true), 0.0)
    }

    /// The criteria after the tightest screen-space test failed. `shortcut` is off only in
    /// the test that holds the shortcut to the full evaluation.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn decide_rest(
        &self,
        view: &View,
        n: Tested<'_>,
        t: f32,
        d: f32,
        lhs: f64,
        d4: f64,
        shortcut: bool,
    ) -> Decision {
        let ignore_outside = self.criteria.frustum == FrustumMode::Ignore;
        if !ignore_outside && self.outside(view, n) {
            return Decision::Fold;
        }
        // The error exceeds even the loosest threshold a facing could give (`t`: no gaze,
        // and silhouettes only tighten), and the node cannot be entirely backfacing: it
        // unfolds whatever its facing, without the cone test's square roots.
        if shortcut
            && self.criteria.gaze.is_none()
            && self.criteria.silhouette_factor.is_none_or(|s| s <= 1.0)
            && lhs > f64::from(t) * f64::from(t) * d4
            && !self.may_face_away(view, n)
        {
            return Decision::Unfold;
        }
        let facing = if self.criteria.backface || self.criteria.silhouette_factor.is_some() {
            self.facing(view, n)
        } else {
            Facing::Front
        };
        if self.criteria.backface && facing == Facing::Back {
            return Decision::Fold;
        }
        if d <= 0.0 {
            return Decision::Unfold;
        }
        let mut limit = t * self.gaze_factor(view, n);
        if let (Some(s), Facing::Silhouette) = (self.criteria.silhouette_factor, facing) {
            limit *= s;
        }
        let limit = f64::from(limit);
        if lhs > limit * limit * d4 {
            Decision::Unfold
        } else {
            Decision::Fold
        }
    }

    /// The priority of unfolding `n` (whose surface error is `surface_error`) in budget
    /// mode: its screen-space error in pixels divided by the factor its criteria scale the
    /// threshold by (silhouette, gaze), so that priorities rank nodes as a threshold would.
    /// The error is the one [`Criteria::bound`] names, projected from the node's ball. Zero
    /// for nodes outside the frustum or entirely backfacing; the object-space error when
    /// view-independent.
    pub fn priority(&self, n: Tested<'_>, surface_error: f32) -> f32 {
        let ranked = match self.criteria.bound {
            Bound::Vertex => n.hot.error_radius,
            Bound::Surface => surface_error + TIE_BREAK * n.hot.error_radius,
        };
        let Some(view) = &self.view else {
            return ranked;
        };
        if self.criteria.frustum != FrustumMode::Off && self.outside(view, n) {
            return 0.0;
        }
        let r = n.hot.error_radius;
        if r == 0.0 {
            return 0.0;
        }
        let facing = self.facing(view, n);
        if self.criteria.backface && facing == Facing::Back {
            return 0.0;
        }
        let c = view.to_camera(Vec3::from(n.hot.proxy));
        // Nearness from the whole ball, whichever error is ranked.
        let d = c.z - r;
        let error = if d <= 0.0 {
            f32::MAX
        } else {
            screen_bound(view.focal_px, ranked, d, c)
        };
        let mut scale = self.gaze_factor(view, n);
        if let (Some(s), Facing::Silhouette) = (self.criteria.silhouette_factor, facing) {
            scale *= s;
        }
        (error / scale).min(f32::MAX)
    }

    /// The screen-space error bound of `n` in pixels ([`f32::INFINITY`] when its ball reaches
    /// the eye plane), or its error radius when view-independent.
    pub fn screen_error(&self, n: Tested<'_>) -> f32 {
        self.screen_error_of(n.hot)
    }

    /// [`Judge::screen_error`] from the node's hot record alone (all it reads).
    #[inline]
    pub fn screen_error_of(&self, hot: &Hot) -> f32 {
        let Some(view) = &self.view else {
            return hot.error_radius;
        };
        let r = hot.error_radius;
        let c = view.to_camera(Vec3::from(hot.proxy));
        let d = c.z - r;
        if d <= 0.0 {
            return if r == 0.0 { 0.0 } else { f32::INFINITY };
        }
        screen_bound(view.focal_px, r, d, c)
    }

    #[inline]
    fn outside(&self, view: &View, n: Tested<'_>) -> bool {
        self.criteria.frustum != FrustumMode::Off
            && view.sphere_outside(view.to_camera(Vec3::from(n.shape.center)), n.shape.radius)
    }

    /// False when backface folding is off or `n` cannot test as entirely backfacing: its cone
    /// is empty or two-sided, or its axis does not point away from the eye (backfacing needs
    /// `a·(c − e) > sin(α + β)·‖c − e‖ ≥ 0`, see [`Judge::facing_of`]).
    #[inline]
    fn may_face_away(&self, view: &View, n: Tested<'_>) -> bool {
        let test = n.shape.cone_cos;
        self.criteria.backface
            && (0.0..=1.0).contains(&test)
            && Vec3::from(n.shape.cone_axis).dot(Vec3::from(n.shape.center) - view.eye) > 0.0
    }

    /// How `n`'s triangles face the eye of this judge's camera (front when view-independent).
    pub fn facing_of(&self, n: Tested<'_>) -> Facing {
        match &self.view {
            Some(view) => self.facing(view, n),
            None => Facing::Front,
        }
    }

    /// The cone test without trigonometry: with `d = ‖c − e‖`, `d·cos γ = a·(c − e)`,
    /// `d·cos β = √(d² − R²)` and `d·sin β = R`, so `α + β < π/2` is
    /// `cos α·√(d² − R²) > sin α·R`, and then `γ + α + β < π/2` (backfacing) is
    /// `a·(c − e) > d·sin(α + β) = sin α·√(d² − R²) + cos α·R`, and `γ − α − β > π/2`
    /// (front-facing) is `a·(c − e) < −d·sin(α + β)`.
    ///
    /// A two-sided cone (negative [`crate::store::Shape::cone_cos`]) is the same test about
    /// the axis taken either way: clear of the silhouette band when
    /// `|a·(c − e)| > d·sin(α + β)`.
    fn facing(&self, view: &View, n: Tested<'_>) -> Facing {
        let test = n.shape.cone_cos;
        if test > 1.0 {
            return Facing::Front;
        }
        let two_sided = test < 0.0;
        let cone_cos = test.abs();
        let cone_sin = (1.0 - cone_cos * cone_cos).max(0.0).sqrt();
        let to_center = Vec3::from(n.shape.center) - view.eye;
        let d2 = to_center.length_squared();
        let r = n.shape.radius;
        if d2 <= r * r {
            return Facing::Silhouette;
        }
        let cos_beta_d = (d2 - r * r).sqrt();
        if cone_cos * cos_beta_d <= cone_sin * r {
            return Facing::Silhouette;
        }
        let sin_sum_d = cone_sin * cos_beta_d + cone_cos * r;
        let along = Vec3::from(n.shape.cone_axis).dot(to_center);
        if two_sided {
            return if along.abs() > sin_sum_d {
                Facing::BothSides
            } else {
                Facing::Silhouette
            };
        }
        if along > sin_sum_d {
            Facing::Back
        } else if along < -sin_sum_d {
            Facing::Front
        } else {
            Facing::Silhouette
        }
    }

    fn gaze_factor(&self, view: &View, n: Tested<'_>) -> f32 {
        let Some(gaze) = self.criteria.gaze else {
            return 1.0;
        };
        let to_center = Vec3::from(n.shape.center) - view.eye;
        let distance = to_center.length();
        if distance <= n.shape.radius || self.gaze_direction == Vec3::ZERO {
            return 1.0;
        }
        let angle = (self.gaze_direction.dot(to_center) / distance)
            .clamp(-1.0, 1.0)
            .acos();
        let beta = (n.shape.radius / distance).asin();
        1.0 + gaze.falloff.max(0.0) * (angle - beta).max(0.0)
    }
}

/// The two sides of the screen-space test of an error radius `r` at camera-space position
/// `c`, without the threshold: `(focal²·r²·(d² + (ρ + r)²), d⁴, ρ)` with `d = c.z − r` and
/// `ρ` the distance from the view axis, so that the bound is within `T` pixels exactly when
/// `lhs ≤ T²·d⁴`. A ball reaching the eye plane gives an infinite left side. Both sides hold
/// fourth powers of distances, so they are formed in f64: in f32 they overflow once distances
/// pass about 1.4·10⁹/√T, and an infinite right side would fold everything.
#[inline]
fn screen_test_sides(focal_sq: f32, r: f32, c: Vec3) -> (f64, f64, f32) {
    let d = c.z - r;
    // A NaN distance unfolds, as a ball reaching the eye plane does.
    if d.is_nan() || d <= 0.0 {
        return (f64::INFINITY, 0.0, 0.0);
    }
    // Squares of f32 values cannot overflow f64.
    let (x, y) = (f64::from(c.x), f64::from(c.y));
    let rho = (x * x + y * y).sqrt();
    let (r64, d, reach) = (f64::from(r), f64::from(d), rho + f64::from(r));
    (
        f64::from(focal_sq) * r64 * r64 * (d * d + reach * reach),
        (d * d) * (d * d),
        rho as f32,
    )
}

/// The screen-space error bound in pixels of an error radius `r` whose ball is `d` in front
/// of the eye plane, its proxy at camera-space `c`: `focal·r·√(d² + (ρ + r)²) / d²` with `ρ`
/// the distance from the view axis, all formed in f64 (as in [`screen_test_sides`]) so that
/// squares of large distances cannot overflow; saturating at `f32::MAX`.
fn screen_bound(focal: f32, r: f32, d: f32, c: Vec3) -> f32 {
    let (x, y) = (f64::from(c.x), f64::from(c.y));
    let (r, d, reach) = (
        f64::from(r),
        f64::from(d),
        (x * x + y * y).sqrt() + f64::from(r),
    );
    (f64::from(focal) * r * (d * d + reach * reach).sqrt() / (d * d)).min(f64::from(f32::MAX))
        as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{Hot, Shape};

    /// The shortcut for nodes whose error exceeds the loosest threshold and that cannot face
    /// away gives the decision the full evaluation gives, on random nodes, cameras and
    /// criteria.
    #[test]
    fn the_unfold_shortcut_decides_as_the_full_criteria() {
        let mut next = crate::unit_random(0x9E37_79B9_7F4A_7C15u64);
        let (mut shortcut_taken, mut cases) = (0, 0);
        for _ in 0..50_000 {
            let camera = Camera {
                eye: [next() * 4.0 - 2.0, next() * 4.0 - 2.0, next() * 4.0 - 2.0],
                target: [next() - 0.5, next() - 0.5, next() - 0.5],
                up: [0.0, 1.0, 0.0],
                fov_y_degrees: 30.0 + 60.0 * next(),
                width: 640,
                height: 480,
                near: 0.01,
            };
            let criteria = Criteria {
                silhouette_factor: [None, Some(0.25), Some(1.0)][(next() * 3.0) as usize % 3],
                backface: next() < 0.7,
                frustum: [FrustumMode::Fold, FrustumMode::Off][(next() * 2.0) as usize % 2],
                ..Criteria::default()
            };
            let judge = Judge::new(&Viewpoint::Camera(camera), &criteria);
            let view = judge.view().unwrap();
            let axis = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize_or(Vec3::Z);
            let proxy = [next() - 0.5, next() - 0.5, next() - 0.5];
            let r = 0.001 + 0.05 * next();
            let hot = Hot {
                proxy,
                error_radius: r,
                group_radius: 0.0,
                group_error: 0.0,
                first_child: 0,
                child_count: 0,
            };
            let shape = Shape {
                center: proxy,
                radius: r * (1.0 + next()),
                cone_axis: axis.into(),
                cone_cos: Shape::cone_test(next() * 3.5 - 0.3, next() < 0.3),
            };
            let n = Tested {
                hot: &hot,
                shape: &shape,
            };
            let t = 0.25 + 4.0 * next();
            let c = view.to_camera(Vec3::from(proxy));
            let d = c.z - r;
            let (lhs, d4, _) = screen_test_sides(judge.focal_sq, r, c);
            let tightest = f64::from(judge.tightest(t));
            if lhs <= tightest * tightest * d4 {
                continue;
            }
            cases += 1;
            let fast = judge.decide_rest(view, n, t, d, lhs, d4, true);
            let full = judge.decide_rest(view, n, t, d, lhs, d4, false);
            assert_eq!(
                fast, full,
                "{camera:?} {criteria:?} {hot:?} {shape:?} t {t}"
            );
            shortcut_taken += usize::from(
                fast == Decision::Unfold
                    && lhs > f64::from(t * t) * d4
                    && !judge.may_face_away(view, n),
            );
        }
        assert!(
            cases > 10_000 && shortcut_taken > 1_000,
            "{cases} cases, {shortcut_taken} through the shortcut"
        );
    }
}
