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
//! a quadratic in `u = d − δ` whose root gives the largest such `δ`. A failing test has the
//! mirror margin (`fail_margin`), and the frustum and cone tests theirs
//! ([`crate::criteria`]); a record may hold two outcomes, a group's and its parent's own fold
//! test (`Reuse::with_own`).
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

/// The ball test's sides at the margin, in double precision: the depth `d = z − s` of the
/// ball's near side now, the depth `u` at which the bound meets the threshold `tight` (the
/// positive root of `T·u² + b·u − (b·d + k)` with `b = √2·f·r`, `k = f·r·L`; see the module
/// documentation), and the room left for rounding (the single-precision inputs' relative
/// 1e-7 is far inside it). `None` when the ball reaches the eye plane or `tight` is not
/// positive.
fn meeting_depth(focal: f32, r: f32, z: f32, rho: f32, s: f32, tight: f32) -> Option<[f64; 3]> {
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
        return None;
    }
    let b = std::f64::consts::SQRT_2 * focal * r;
    let k = focal * r * (d * d + (rho + s) * (rho + s)).sqrt();
    // The root in the form without cancellation.
    let c = b * d + k;
    let u = 2.0 * c / (b + (b * b + 4.0 * tight * c).sqrt());
    Some([d, u, 1e-4 * (z.abs() + rho + s)])
}

/// How far (camera coordinates) the centre of a ball test may move before the test could
/// fail: `focal` in pixels, error radius `r`, centre depth `z` and distance from the view
/// axis `rho`, extent `s` of the ball, threshold `tight`. Zero when the test does not pass
/// with room to spare.
pub(crate) fn pass_margin(focal: f32, r: f32, z: f32, rho: f32, s: f32, tight: f32) -> f32 {
    let Some([d, u, slack]) = meeting_depth(focal, r, z, rho, s, tight) else {
        return 0.0;
    };
    let margin = d - u - slack;
    if margin > 0.0 { margin as f32 } else { 0.0 }
}

/// How far (camera coordinates) the centre of a ball test may move before the test could
/// pass: the counterpart of [`pass_margin`] for a test that fails now, with the same
/// arguments. Zero when the test does not fail with room to spare, or the ball reaches the
/// eye plane.
///
/// Two bounds, each sufficient, the larger taken. Under a move of at most `δ` the left side
/// is at least `f·r·(L − √2·δ)` and the depth `d + δ` at most, so the test still fails
/// while `T·(d + δ)² + √2·f·r·δ − f·r·L < 0`: with `u = d + δ` the same quadratic as
/// [`pass_margin`]'s, whose root now lies beyond `d`. That bound lets `L` shrink as `d`
/// grows, which cannot both happen near the view axis; there `L ≥ d` gives the other: the
/// test fails while `f·r > T·(d + δ)`.
pub(crate) fn fail_margin(focal: f32, r: f32, z: f32, rho: f32, s: f32, tight: f32) -> f32 {
    let Some([d, u, slack]) = meeting_depth(focal, r, z, rho, s, tight) else {
        return 0.0;
    };
    let near_axis = f64::from(focal) * f64::from(r) / f64::from(tight);
    let margin = (u - d).max(near_axis - d) - slack;
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
    /// How many frames in a row the camera has not moved.
    still_frames: u32,
}

/// How many frames in a row the camera must have stayed where it is before tests get every
/// margin ([`Now::still`]). A viewer adjusts again after the camera stops only while the cut
/// changes or pages arrive; the first still frame usually finds the cut settled, and working
/// the margins out there would cost a frame that rarely has a successor.
const STILL_FRAMES: u32 = 2;

/// The motion log at the current frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Now {
    travel: f64,
    turn: f64,
    /// A new generation starts with this frame: every earlier record must be cleared.
    pub(crate) fresh: bool,
    /// The camera is where it was for the last [`STILL_FRAMES`] frames of the same
    /// generation: tests made now hold until it moves, and frames for it keep coming, so
    /// they are worth a margin each ([`crate::adjust`]).
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
        let mut moved = true;
        let fresh = match self.previous {
            Some((before, same)) if same == setting => {
                let (travel, turn) = (
                    distance(before.eye.into(), view.eye.into()),
                    turn_bound(&before, view),
                );
                self.travel += travel;
                self.turn += turn;
                moved = travel != 0.0 || turn != 0.0;
                false
            }
            _ => {
                self.travel = 0.0;
                self.turn = 0.0;
                true
            }
        };
        self.previous = Some((*view, setting));
        self.still_frames = if moved { 0 } else { self.still_frames + 1 };
        Some(Now {
            travel: self.travel,
            turn: self.turn,
            fresh,
            still: self.still_frames >= STILL_FRAMES,
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
pub(crate) fn turn_bound(before: &View, after: &View) -> f64 {
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
    /// How much sooner than `until` a second outcome held with it ends: an active node's own
    /// fold test beside its boundary children's ([`crate::adjust`]); infinite when there is
    /// none. It fills what would be padding.
    own_sooner: f32,
    /// The value of `turn·reach + travel` up to which the outcome holds.
    until: f64,
}

impl Reuse {
    /// No test to reuse.
    pub(crate) const NONE: Reuse = Reuse {
        reach: 0.0,
        own_sooner: f32::INFINITY,
        until: f64::NEG_INFINITY,
    };

    /// An outcome found now with `margin`, for points within `reach` of the eye.
    pub(crate) fn new(now: &Now, reach: f32, margin: f32) -> Reuse {
        Reuse {
            reach,
            own_sooner: f32::INFINITY,
            until: now.turn * f64::from(reach) + now.travel + f64::from(margin),
        }
    }

    /// This outcome (holding now) with a second one found now with a finite `margin`, for
    /// points within `reach` of the eye ([`Reuse::own_holds`]). A larger reach than this
    /// one's widens both: the first then holds while the motion at the larger reach stays
    /// below what was left of its margin, which bounds the motion at its own reach.
    pub(crate) fn with_own(self, now: &Now, reach: f32, margin: f32) -> Reuse {
        let at = |reach: f32| now.turn * f64::from(reach) + now.travel;
        let mut widened = self;
        if reach > self.reach {
            widened.reach = reach;
            widened.until = at(reach) + (self.until - at(self.reach));
        }
        let own_until = at(widened.reach) + f64::from(margin);
        if widened.until == f64::INFINITY {
            // A first outcome that holds for good (children of zero error) is cut short to
            // end with the second: the difference must be finite.
            widened.until = own_until;
            return Reuse {
                own_sooner: 0.0,
                ..widened
            };
        }
        Reuse {
            // Rounded up, so the second outcome never outlasts its margin.
            own_sooner: ((widened.until - own_until) as f32).next_up(),
            ..widened
        }
    }

    /// Distance from the eye, at the test, of the farthest point the outcome depends on.
    pub(crate) fn reach(&self) -> f32 {
        self.reach
    }

    /// How much of the second outcome's margin is left now (negative once it no longer
    /// holds).
    pub(crate) fn own_left(&self, now: &Now) -> f32 {
        let at = now.turn * f64::from(self.reach) + now.travel;
        (self.until - f64::from(self.own_sooner) - at) as f32
    }

    /// True when the second outcome ([`Reuse::with_own`]) still holds.
    #[inline]
    pub(crate) fn own_holds(&self, now: &Now) -> bool {
        // Most records have no second outcome: one comparison says so.
        self.own_sooner < f32::INFINITY
            && now.turn * f64::from(self.reach) + now.travel
                < self.until - f64::from(self.own_sooner)
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
    fn the_test_fails_everywhere_within_the_fail_margin() {
        let mut next = crate::unit_random(0x1405_7B7E_F767_814Fu64);
        let mut positive = 0;
        for _ in 0..20_000 {
            let focal = 200.0 + 2000.0 * next();
            let r = 0.001 + 0.05 * next();
            let s = r * (1.0 + 3.0 * next());
            let z = s + 0.01 + 2.0 * next();
            let rho = 2.0 * next();
            let tight = 0.25 + 5.0 * next();
            let margin = fail_margin(focal, r, z, rho, s, tight);
            if margin == 0.0 {
                continue;
            }
            positive += 1;
            assert!(!passes(focal, r, z, rho, s, tight));
            // The worst moves take depth up and the distance from the axis down by the whole
            // margin, each; try those and others.
            for (dz, drho) in [
                (1.0, -1.0),
                (1.0, 0.0),
                (0.0, -1.0),
                (0.7, -0.7),
                (-1.0, 1.0),
            ] {
                let (z2, rho2) = (z + dz * margin, (rho + drho * margin).max(0.0));
                assert!(
                    !passes(focal, r, z2, rho2, s, tight),
                    "margin {margin} at z {z} rho {rho} r {r} s {s} t {tight}"
                );
            }
        }
        assert!(positive > 1000, "only {positive} tests had a margin");
    }

    #[test]
    fn a_fail_margin_is_close_to_the_largest_move_that_keeps_the_test() {
        // On the view axis, moving straight away from the eye: the test passes at some depth,
        // and the margin should reach a good part of the way there.
        let (focal, r, s, tight, rho) = (1000.0f32, 0.01f32, 0.01f32, 1.0f32, 0.0f32);
        let z = 5.0f32;
        let margin = fail_margin(focal, r, z, rho, s, tight);
        let mut passes_at = z;
        while !passes(focal, r, passes_at, rho, s, tight) {
            passes_at += 0.01;
        }
        let room = passes_at - z;
        assert!(margin > 0.5 * room && margin <= room, "{margin} of {room}");
    }

    /// Two outcomes in one record: each holds exactly as long as its own record would (up
    /// to rounding, on the safe side), whichever ends first and whatever the reaches.
    #[test]
    fn a_second_outcome_holds_as_long_as_its_own_record() {
        let at = |travel: f64, turn: f64| Now {
            travel,
            turn,
            fresh: false,
            still: false,
        };
        let start = at(5.0, 0.25);
        for (first_reach, first_margin) in [(10.0f32, 3.0f32), (30.0, 0.5), (10.0, f32::INFINITY)] {
            for (own_reach, own_margin) in [(10.0f32, 1.0f32), (40.0, 2.0), (5.0, 6.0)] {
                let first = Reuse::new(&start, first_reach, first_margin);
                let both = first.with_own(&start, own_reach, own_margin);
                let own = Reuse::new(&start, own_reach, own_margin);
                for step in 0..400 {
                    let later = at(
                        5.0 + 0.01 * f64::from(step),
                        0.25 + 0.0005 * f64::from(step),
                    );
                    // Never longer than alone; and the first exactly as long, unless it was
                    // widened to a longer reach or cut short to end with the second.
                    assert!(!both.own_holds(&later) || own.holds(&later));
                    assert!(!both.holds(&later) || first.holds(&later));
                    if own_reach <= first_reach && first_margin.is_finite() {
                        assert_eq!(both.holds(&later), first.holds(&later));
                    }
                    let close = |a: Reuse| {
                        let near = at(later.travel + 1e-3, later.turn);
                        a.holds(&later) != a.holds(&near)
                    };
                    if own_reach == first_reach && !close(own) {
                        assert_eq!(both.own_holds(&later), own.holds(&later), "{step}");
                    }
                }
            }
        }
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
