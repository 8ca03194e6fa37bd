//! An estimate, not a timing: how many of a threshold cut's frontier tests a per-node slack
//! could skip along a camera path (`vds-bench cut --vdt FILE --slack-estimate`).
//!
//! Every frame the cut is adjusted as usual; then each node of its frontier (boundary nodes
//! with children, which would unfold, and active nodes whose children are all on the
//! boundary, which would fold) is given the number of further frames its decision surely
//! holds if the camera keeps moving as it did this frame (translation `v`, rotation `w`). The
//! screen-space bound of a node at distance `R` and angle `phi` off the view axis grows as
//! `1 / (R cos² phi)` (its error radius small beside `R`); after `k` frames the node is at
//! least `R − k v` away and at most `k w + asin(k v / R)` further off the axis, so the bound
//! is at most `R cos² phi / ((R − k v) cos² (phi + k w + asin(k v / R)))` times what it is
//! now, and at least the same with the signs turned. A node whose decision holds for `k`
//! frames needs a test once in `k + 1` frames, and the estimate is the sum of those rates.
//! Nodes whose state is not their error's (folded by the frustum or facing away, or whose
//! ball reaches the eye plane) count as tested every frame. An active node's slack is its
//! error's alone: leaving the frustum or turning away would fold it sooner, so its figures
//! are a lower bound of the tests. Silhouettes are off, so that every other decision is the
//! error's against `t`.
//!
//! The same sum is printed with a fold band `h`: an active node folds only once its error is
//! below `t / (1 + h)` (unfolds still happen above `t`, so the bound holds), which gives the
//! nodes that just unfolded room to move back. The cut itself is the exact one in every
//! case, so the band's figures are of its slack alone, not of the cut it would keep.

use anyhow::Result;
use glam::Vec3;
use vds_runtime::store::Hot;
use vds_runtime::{CameraPath, Criteria, Goal, Judge, Viewpoint};

/// Fold bands printed, as `h` in `t / (1 + h)`.
const BANDS: [f32; 3] = [0.0, 0.25, 1.0];

/// Frames of slack counted at most.
const MOST_FRAMES: u32 = 256;

/// Prints the estimate for `path` at threshold `t` over the whole resident file `bytes`.
pub fn run(bytes: &[u8], path: &CameraPath, t: f32) -> Result<()> {
    // Every page resident and no budget: the effective threshold stays `t` (checked below).
    let mut runtime = crate::cut::resident_ranks(bytes)?;
    let criteria = Criteria {
        silhouette_factor: None,
        ..Criteria::default()
    };
    let mut rates = [0f64; BANDS.len()];
    let (mut frontier, mut by_other, mut changed) = (0u64, 0u64, 0u64);
    let mut before: Option<(Vec3, Vec3)> = None;
    let mut steps = Vec::new();
    for camera in &path.cameras {
        let viewpoint = Viewpoint::Camera(*camera);
        let frame = runtime.adjust(&viewpoint, &criteria, Goal::Threshold(t))?;
        anyhow::ensure!(
            frame.effective_threshold == Some(t),
            "the threshold was raised to {:?}",
            frame.effective_threshold
        );
        let eye = Vec3::from(camera.eye);
        let forward = (Vec3::from(camera.target) - eye).normalize_or_zero();
        let Some((eye_before, forward_before)) = before.replace((eye, forward)) else {
            continue;
        };
        let step = Step {
            v: (eye - eye_before).length(),
            w: forward_before.dot(forward).clamp(-1.0, 1.0).acos(),
        };
        steps.push((step.v, step.w));
        let judge = Judge::new(&viewpoint, &criteria);
        let cut = runtime.cut();
        let store = cut.store();
        let boundary = cut.boundary();
        let unfolding = boundary
            .iter()
            .map(|&id| store.hot(id))
            .filter(|hot| hot.child_count > 0)
            .map(|hot| (hot, true));
        let folding = cut
            .active_entries()
            .iter()
            .filter(|entry| entry.active_children == 0)
            .map(|entry| (&entry.hot, false));
        for (hot, folded) in unfolding.chain(folding) {
            frontier += 1;
            match step.frames_held(&judge, hot, folded, t) {
                None => {
                    by_other += 1;
                    rates.iter_mut().for_each(|rate| *rate += 1.0);
                }
                Some(held) => {
                    for (rate, held) in rates.iter_mut().zip(held) {
                        *rate += 1.0 / f64::from(held + 1);
                    }
                }
            }
        }
        changed += u64::from(frame.stats.unfolds + frame.stats.folds);
    }
    // A frame counts from the second camera on: the first has no step.
    let frames = steps.len();
    let per_frame = |n: f64| n / frames.max(1) as f64;
    let median = |mut values: Vec<f32>| {
        values.sort_by(f32::total_cmp);
        values.get(values.len() / 2).copied().unwrap_or(0.0)
    };
    println!(
        "  t={t} px: frontier {:.0} tests a frame ({:.0} decided otherwise than by the error), \
         {:.0} nodes changed a frame (means over {frames} frames); the eye moved {:.3} and \
         turned {:.4} rad a frame (medians)",
        per_frame(frontier as f64),
        per_frame(by_other as f64),
        per_frame(changed as f64),
        median(steps.iter().map(|s| s.0).collect()),
        median(steps.iter().map(|s| s.1).collect()),
    );
    for (h, rate) in BANDS.iter().zip(rates) {
        println!(
            "    fold band h = {h}: ~{:.0} tests a frame with per-node slack ({:.1} % of the \
             frontier's)",
            per_frame(rate),
            100.0 * rate / frontier.max(1) as f64
        );
    }
    Ok(())
}

/// A frame's camera motion: how far the eye moved, and by what angle the view turned.
struct Step {
    v: f32,
    w: f32,
}

impl Step {
    /// For each of [`BANDS`], the frames after this one for which `hot`'s decision surely
    /// holds (folded: it stays within `t`; active: it stays above the band's fold limit),
    /// or `None` if its decision is not its error's.
    fn frames_held(
        &self,
        judge: &Judge,
        hot: &Hot,
        folded: bool,
        t: f32,
    ) -> Option<[u32; BANDS.len()]> {
        let ratio = judge.screen_error_of(hot) / t;
        if folded == (ratio >= 1.0) || !ratio.is_finite() {
            return None;
        }
        let c = judge.view()?.to_camera(Vec3::from(hot.proxy));
        let r0 = c.length().max(1e-6);
        let phi0 = (c.z / r0).clamp(-1.0, 1.0).acos();
        // The bound after `k` frames over the bound now, at most (folded: the node comes
        // closer and turns off the axis) or at least (active: it moves away and onto it).
        // Its direction from the eye turns with the view, and by up to asin(k v / R) as the
        // eye moves k v.
        let growth = |k: u32| {
            let k = k as f32;
            let turn = k * self.w + (k * self.v / r0).min(1.0).asin();
            let (r, phi) = if folded {
                ((r0 - k * self.v).max(1e-6), (phi0 + turn).min(1.55))
            } else {
                (r0 + k * self.v, (phi0 - turn).max(0.0))
            };
            (r0 * phi0.cos().powi(2)) / (r * phi.cos().powi(2)).max(1e-12)
        };
        // The largest k up to MOST_FRAMES for which `holds`: the growth is monotone.
        let frames_held_by = |holds: &dyn Fn(u32) -> bool| {
            let (mut held, mut fails) = (0, MOST_FRAMES + 1);
            while fails - held > 1 {
                let mid = (held + fails) / 2;
                if holds(mid) {
                    held = mid;
                } else {
                    fails = mid;
                }
            }
            held
        };
        Some(if folded {
            // The band changes only when active nodes fold.
            [frames_held_by(&|k| ratio * growth(k) <= 1.0); BANDS.len()]
        } else {
            BANDS.map(|h| frames_held_by(&|k| ratio * growth(k) >= 1.0 / (1.0 + h)))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vds_runtime::Camera;

    /// A camera at (0, 0, 10) looking down the z axis at the origin.
    fn camera() -> Camera {
        Camera {
            eye: [0.0, 0.0, 10.0],
            target: [0.0, 0.0, 0.0],
            up: [0.0, 1.0, 0.0],
            fov_y_degrees: 60.0,
            width: 800,
            height: 600,
            near: 0.01,
        }
    }

    /// A node straight ahead at distance 10 whose bound is `ratio` of the threshold 1 px.
    fn ahead(ratio_wanted: f32) -> (Judge, Hot, f32) {
        let judge = Judge::new(&Viewpoint::Camera(camera()), &Criteria::default());
        let mut hot = Hot {
            proxy: [0.0; 3],
            error_radius: 0.001,
            group_radius: 0.0,
            group_error: 0.0,
            first_child: 1,
            child_count: 2,
        };
        // The bound is nearly linear in the radius this far away: scale it to the ratio.
        hot.error_radius *= ratio_wanted / judge.screen_error_of(&hot);
        let ratio = judge.screen_error_of(&hot);
        (judge, hot, ratio)
    }

    #[test]
    fn a_folded_node_ahead_holds_until_the_eye_comes_close_enough() {
        let (judge, hot, ratio) = ahead(0.5);
        let step = Step { v: 0.5, w: 0.0 };
        let held = step.frames_held(&judge, &hot, true, 1.0).unwrap();
        // After k frames it may be 10 − k/2 away and asin(k/20) off the axis (the eye moved
        // sideways): the bound is then ratio · 10 / ((10 − k/2) (1 − (k/20)²)) at most.
        let holds = |k: u32| {
            let k = k as f32;
            ratio * 10.0 / ((10.0 - k / 2.0) * (1.0 - (k / 20.0).powi(2))) <= 1.0
        };
        for h in held {
            assert!(h > 0 && holds(h) && !holds(h + 1), "{held:?}");
        }
    }

    #[test]
    fn an_off_axis_node_holds_for_every_motion_within_the_steps() {
        let camera = camera();
        let judge_at =
            |camera: Camera| Judge::new(&Viewpoint::Camera(camera), &Criteria::default());
        // 10 from the eye, 30° off the view axis.
        let (sin, cos) = 30f32.to_radians().sin_cos();
        let mut hot = Hot {
            proxy: [10.0 * sin, 0.0, 10.0 - 10.0 * cos],
            error_radius: 0.001,
            group_radius: 0.0,
            group_error: 0.0,
            first_child: 1,
            child_count: 2,
        };
        hot.error_radius *= 0.5 / judge_at(camera).screen_error_of(&hot);
        let moved = |by: Vec3, turn: f32| {
            let eye = Vec3::from(camera.eye) + by;
            let (s, c) = turn.sin_cos();
            Camera {
                eye: eye.into(),
                target: (eye + Vec3::new(-10.0 * s, 0.0, -10.0 * c)).into(),
                ..camera
            }
        };
        let toward = (Vec3::from(hot.proxy) - Vec3::from(camera.eye)).normalize();
        let directions = [toward, Vec3::NEG_Z, Vec3::X, Vec3::NEG_X, Vec3::Y];
        for step in [
            Step { v: 0.2, w: 0.0 },
            Step { v: 0.0, w: 0.02 },
            Step { v: 0.1, w: 0.01 },
        ] {
            let held = step
                .frames_held(&judge_at(camera), &hot, true, 1.0)
                .unwrap()[0];
            assert!(held > 0, "no slack at all");
            let k = held as f32;
            for direction in directions {
                for turn in [-k * step.w, k * step.w] {
                    let ratio = judge_at(moved(direction * k * step.v, turn)).screen_error_of(&hot);
                    assert!(
                        ratio <= 1.0 + 1e-3,
                        "{held} frames: {ratio} after {direction}, {turn}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_fold_band_lets_an_active_node_move_further_away() {
        let (judge, hot, ratio) = ahead(1.1);
        let step = Step { v: 0.5, w: 0.0 };
        let held = step.frames_held(&judge, &hot, false, 1.0).unwrap();
        // ratio · 10 / (10 + k · 0.5) ≥ 1 / (1 + h) while k ≤ 20 (ratio (1 + h) − 1).
        for (h, held) in BANDS.iter().zip(held) {
            let expected = 20.0 * (ratio * (1.0 + h) - 1.0);
            assert!(
                (held as f32 - expected).abs() <= 1.0,
                "h {h}: {held}, {expected}"
            );
        }
        assert!(held[0] < held[1] && held[1] < held[2]);
        // Its decision is not its error's once folded with the same ratio.
        assert_eq!(step.frames_held(&judge, &hot, true, 1.0), None);
    }
}
