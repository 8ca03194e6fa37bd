//! Reusing a threshold test from an earlier frame while the camera has not moved enough to
//! change its outcome.
//!
//! Along a smooth camera path most of the threshold traversal's work repeats itself: a group
//! of boundary children that passed the test last frame, with room to spare, passes again.
//! When a test passes, this module computes its *margin*: how far the tested ball's centre may
//! move in camera coordinates before the test could fail. The traversal then skips the test
//! until the camera has moved that far.
//!
//! ## The margin
//! The test ([`crate::criteria`]) passes when `f·r·√(d² + (ρ + s)²) ≤ T·d²` with `d = z − s`
//! (`z`, `ρ`: the centre's depth and distance from the view axis; `r`: the error radius; `s`:
//! the ball's extent, `r` for one node and the group radius for a group). If the centre moves
//! by at most `δ`, then `z` and `ρ` each change by at most `δ`, so the left side is at most
//! `f·r·(L + √2·δ)` with `L = √(d² + (ρ + s)²)` (triangle inequality) and the right side at
//! least `T·(d − δ)²`. The test therefore still passes while `T·(d − δ)² − √2·f·r·δ − f·r·L ≥ 0`,
//! a quadratic in `u = d − δ` whose root gives the largest such `δ`.
//!
//! ## Camera motion
//! A world point `p` sits at `c = R·(p − e)` in camera coordinates (`R` the rows right, up,
//! forward; `e` the eye). From the frame a test ran in (`R₀`, `e₀`) to now (`R`, `e`),
//! `c − c₀ = (R − R₀)·(p − e₀) + R·(e₀ − e)`, so `‖c − c₀‖ ≤ ‖R − R₀‖·‖p − e₀‖ + ‖e − e₀‖`.
//! The log sums, frame by frame, an upper bound of `‖R − R₀‖` (the smaller of the Frobenius
//! norm and `√(‖·‖₁‖·‖∞)` of the change of basis, both bounds of the operator norm) as
//! *turn*, and the eye's travel as *travel*; by the triangle inequality the sums bound the
//! motion since any earlier frame. A test with margin `δ` for a point at distance `D` from the
//! eye then holds while `turn·D + travel` has grown by less than `δ`. Any change of threshold,
//! criteria or camera intrinsics starts a new *generation*, which no earlier test survives.

use crate::criteria::{Criteria, Judge};
use crate::view::View;

/// How far (camera coordinates) the centre of a ball test may move before the test could
/// fail: `focal` in pixels, error radius `r`, centre depth `z` and distance from the view
/// axis `rho`, extent `s` of the ball, threshold `tight`. Zero when the test does not pass
/// with room to spare.
pub(crate) fn pass_margin(focal: f32, r: f32, z: f32, rho: f32, s: f32, tight: f32) -> f32 {
    let (focal, r, z, rho, s, tight) = (
        f64::from(focal),
        f64::from(r),
        f64::from(z),
        f64::from(rho),
        f64::from(s),
        f64::from(tight),
    );
    let d = z - s;
    if d <= 0.0 || tight <= 0.0 {
        return 0.0;
    }
    let b = std::f64::consts::SQRT_2 * focal * r;
    let k = focal * r * (d * d + (rho + s) * (rho + s)).sqrt();
    // The root of T·u² + b·u − (b·d + k), in the form without cancellation: the depth at
    // which the bound meets the threshold.
    let c = b * d + k;
    let u = 2.0 * c / (b + (b * b + 4.0 * tight * c).sqrt());
    // Rounding of the single-precision inputs (relative 1e-7) is far inside this slack.
    let margin = d - u - 1e-4 * (z.abs() + rho + s);
    if margin > 0.0 { margin as f32 } else { 0.0 }
}

/// What a reused test must agree with: everything but the camera's pose.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Setting {
    threshold: f32,
    criteria: Criteria,
    focal_px: f32,
    tan_x: f32,
    tan_y: f32,
    near: f32,
}

/// The camera's accumulated motion (see the module documentation).
#[derive(Debug, Default)]
pub(crate) struct MotionLog {
    previous: Option<(View, Setting)>,
    travel: f64,
    turn: f64,
}

/// The motion log at the current frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Now {
    travel: f64,
    turn: f64,
    /// A new generation starts with this frame: every earlier record must be cleared.
    pub(crate) fresh: bool,
    /// The camera is where it was at the previous frame of the same generation: every test
    /// gives what it gave then, for the same node ([`crate::adjust`], still passes).
    pub(crate) still: bool,
}

impl MotionLog {
    /// `judge` as it will see the scene `frames` frames from now if the camera keeps moving
    /// as it moved since the last logged frame (call before [`MotionLog::advance`]); `None`
    /// without a camera, a previous frame of the same setting, or any motion.
    pub(crate) fn ahead(&self, judge: &Judge, threshold: f32, frames: f32) -> Option<Judge> {
        let view = judge.view()?;
        let (before, setting) = self.previous.as_ref()?;
        if setting.threshold != threshold || setting.criteria != *judge.criteria() || before == view
        {
            return None;
        }
        Some(judge.with_view(view.extrapolated(before, frames)))
    }

    /// Logs this frame's camera; `None` without a camera (nothing to reuse then). The
    /// first frame, and any frame whose threshold, criteria or camera intrinsics differ from
    /// the previous one's, starts a new generation.
    pub(crate) fn advance(&mut self, judge: &Judge, threshold: f32) -> Option<Now> {
        let Some(view) = judge.view() else {
            self.previous = None;
            return None;
        };
        let setting = Setting {
            threshold,
            criteria: *judge.criteria(),
            focal_px: view.focal_px,
            tan_x: view.tan_x,
            tan_y: view.tan_y,
            near: view.near,
        };
        let mut still = false;
        let fresh = match self.previous {
            Some((before, same)) if same == setting => {
                let (travel, turn) = (
                    distance(before.eye.into(), view.eye.into()),
                    turn_bound(&before, view),
                );
                self.travel += travel;
                self.turn += turn;
                still = travel == 0.0 && turn == 0.0;
                false
            }
            _ => {
                self.travel = 0.0;
                self.turn = 0.0;
                true
            }
        };
        self.previous = Some((*view, setting));
        Some(Now {
            travel: self.travel,
            turn: self.turn,
            fresh,
            still,
        })
    }
}

fn distance(a: [f32; 3], b: [f32; 3]) -> f64 {
    (0..3)
        .map(|k| (f64::from(a[k]) - f64::from(b[k])).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// An upper bound of the operator norm of the change of the camera basis between two views.
fn turn_bound(before: &View, after: &View) -> f64 {
    let rows = |v: &View| [v.right, v.up, v.forward].map(|r| r.to_array());
    let (b, a) = (rows(before), rows(after));
    let m: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| f64::from(a[i][j]) - f64::from(b[i][j])));
    let frobenius = m.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
    let max_row = m
        .iter()
        .map(|row| row.iter().map(|x| x.abs()).sum::<f64>())
        .fold(0.0, f64::max);
    let max_column = (0..3)
        .map(|j| (0..3).map(|i| m[i][j].abs()).sum::<f64>())
        .fold(0.0, f64::max);
    frobenius.min((max_row * max_column).sqrt())
}

/// A test outcome that holds while the camera's motion stays below a limit. Records are
/// cleared when a new generation starts (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reuse {
    /// Distance from the eye, at the test, of the farthest point the test depends on.
    reach: f32,
    /// The value of `turn·reach + travel` up to which the outcome holds.
    until: f64,
}

impl Reuse {
    /// No test to reuse.
    pub(crate) const NONE: Reuse = Reuse {
        reach: 0.0,
        until: f64::NEG_INFINITY,
    };

    /// An outcome found now with `margin`, for points within `reach` of the eye.
    pub(crate) fn new(now: &Now, reach: f32, margin: f32) -> Reuse {
        Reuse {
            reach,
            until: now.turn * f64::from(reach) + now.travel + f64::from(margin),
        }
    }

    /// True when the outcome still holds.
    #[inline]
    pub(crate) fn holds(&self, now: &Now) -> bool {
        now.turn * f64::from(self.reach) + now.travel < self.until
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The test a margin is computed for, as `criteria.rs` evaluates it.
    fn passes(focal: f32, r: f32, z: f32, rho: f32, s: f32, tight: f32) -> bool {
        let d = f64::from(z) - f64::from(s);
        let (f, r) = (f64::from(focal), f64::from(r));
        d > 0.0
            && f * f * r * r * (d * d + (f64::from(rho) + f64::from(s)).powi(2))
                <= f64::from(tight).powi(2) * d.powi(4)
    }

    #[test]
    fn the_test_passes_everywhere_within_the_margin() {
        let mut next = crate::unit_random(0x2545_F491_4F6C_DD1Du64);
        let mut positive = 0;
        for _ in 0..20_000 {
            let focal = 200.0 + 2000.0 * next();
            let r = 0.001 + 0.05 * next();
            let s = r * (1.0 + 3.0 * next());
            let z = 0.1 + 10.0 * next();
            let rho = 5.0 * next();
            let tight = 0.25 + 5.0 * next();
            let margin = pass_margin(focal, r, z, rho, s, tight);
            if margin == 0.0 {
                continue;
            }
            positive += 1;
            assert!(passes(focal, r, z, rho, s, tight));
            // Any move of the centre by at most the margin: the worst moves depth down and
            // the distance from the axis up by the whole margin, each; try those and others.
            for (dz, drho) in [
                (-1.0, 1.0),
                (-1.0, 0.0),
                (0.0, 1.0),
                (-0.7, 0.7),
                (1.0, -1.0),
            ] {
                let (z2, rho2) = (z + dz * margin, (rho + drho * margin).max(0.0));
                assert!(
                    passes(focal, r, z2, rho2, s, tight),
                    "margin {margin} at z {z} rho {rho} r {r} s {s} t {tight}"
                );
            }
        }
        assert!(positive > 1000, "only {positive} tests had a margin");
    }

    #[test]
    fn the_turn_bound_bounds_how_far_any_point_moves() {
        use crate::view::Camera;
        let mut seed = 7u64;
        let mut next = || {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            ((seed >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        };
        for _ in 0..2000 {
            let camera = |eye: [f32; 3], target: [f32; 3]| {
                Camera {
                    eye,
                    target,
                    up: [0.0, 1.0, 0.0],
                    fov_y_degrees: 50.0,
                    width: 640,
                    height: 480,
                    near: 0.01,
                }
                .view()
            };
            let eye = [next(), next(), next()];
            let target = [next() * 3.0, next() * 3.0, next() * 3.0];
            // Small turns as along a path, and large ones.
            let scale = if next() > 0.0 { 0.02 } else { 1.0 };
            let turned = [0, 1, 2].map(|k| target[k] + scale * next());
            let (a, b) = (camera(eye, target), camera(eye, turned));
            let bound = turn_bound(&a, &b);
            for _ in 0..50 {
                let p = glam::Vec3::new(next(), next(), next()) * 10.0;
                let moved = f64::from((a.to_camera(p) - b.to_camera(p)).length());
                let distance = f64::from((p - a.eye).length());
                assert!(
                    moved <= bound * distance * (1.0 + 1e-5) + 1e-5,
                    "moved {moved} > {bound} x {distance}"
                );
            }
        }
    }

    #[test]
    fn a_margin_is_close_to_the_largest_move_that_keeps_the_test() {
        // On the view axis, moving straight towards the eye: the test fails at some depth,
        // and the margin should reach a good part of the way there.
        let (focal, r, s, tight, rho) = (1000.0f32, 0.01f32, 0.01f32, 1.0f32, 0.0f32);
        let z = 40.0f32;
        let margin = pass_margin(focal, r, z, rho, s, tight);
        let mut fails_at = z;
        while passes(focal, r, fails_at, rho, s, tight) {
            fails_at -= 0.01;
        }
        let room = z - fails_at;
        assert!(margin > 0.5 * room && margin <= room, "{margin} of {room}");
    }
}
