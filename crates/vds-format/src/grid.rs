//! The quantisation grid of a file: every position is stored as integer steps from the
//! scene's lower corner. 2¹⁸ steps span the largest extent, so a step is under 4·10⁻⁶ of the
//! scene's size: 0.6 µm on the 15 cm bunny, 0.4 mm on a 100 m submarine, a pixel at 250×
//! zoom on a full-HD view of the whole scene. (2²¹ steps cost the bunny 1.6 B/triangle
//! more; 2¹⁶ saved 1 B/triangle but is coarse for small parts of large assemblies.)
//!
//! The builder snaps the scene to this grid *before* building, so leaf positions, and every
//! bound computed from them, are exact for the geometry the file holds; the writer then only
//! has to widen bounds for the proxies, centres and axes it quantises itself.

/// Steps along the largest extent.
pub const GRID_STEPS: u32 = 1 << 18;

/// How near a half step a quotient by multiplication must be for [`Grid::quantize`] to divide
/// instead (over four times the multiplication's largest error in the grid's range, 2⁻³²).
const NEAR_HALF_STEP: f64 = 1e-9;

/// A uniform grid: `position = origin + step * coordinate` (per axis, in `f32`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// The lower corner.
    pub origin: [f32; 3],
    /// The spacing; positive and finite.
    pub step: f32,
}

impl Grid {
    /// The grid for a scene with this bounding box.
    pub fn for_bounds(min: [f32; 3], max: [f32; 3]) -> Grid {
        let extent = (0..3)
            .map(|k| f64::from(max[k]) - f64::from(min[k]))
            .fold(0.0f64, f64::max);
        let step = (extent / f64::from(GRID_STEPS - 1)) as f32;
        Grid {
            origin: min,
            step: if step.is_normal() {
                step.next_up()
            } else {
                f32::MIN_POSITIVE
            },
        }
    }

    /// The nearest grid coordinate of `p` (clamped to the grid).
    #[inline]
    pub fn quantize(&self, p: [f32; 3]) -> [u32; 3] {
        let step = f64::from(self.step);
        // One division for three coordinates (the writer quantises every node, and three
        // divisions were 15 % of its time). `offset * inverse` is within 3 ulp of
        // `offset / step`: under 2⁻³² of a step where the quotient is below 2¹⁹, past which both
        // clamp alike. Only a quotient within that of a half step could round otherwise, so
        // near one the division decides: the result is the division's, bit for bit.
        let inverse = 1.0 / step;
        // A plain loop: `[0, 1, 2].map` left its closure out of line (5 % of writing the
        // bunny's file).
        let mut q = [0u32; 3];
        for k in 0..3 {
            let offset = f64::from(p[k]) - f64::from(self.origin[k]);
            q[k] = nearest_steps(offset, step, inverse).clamp(0, i64::from(GRID_STEPS)) as u32;
        }
        q
    }

    /// The position of a grid coordinate. Readers and writers use this one function, so the
    /// values agree bit for bit.
    pub fn dequantize(&self, q: [u32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|k| self.origin[k] + self.step * q[k] as f32)
    }

    /// `p` moved to its nearest grid position.
    pub fn snap(&self, p: [f32; 3]) -> [f32; 3] {
        self.dequantize(self.quantize(p))
    }

    /// A length rounded up to whole steps (one extra step absorbs `f32` rounding of
    /// `units * step` on the reader's side).
    pub fn units_up(&self, length: f64) -> u32 {
        let units = (length / f64::from(self.step)).ceil() + 1.0;
        units.clamp(0.0, f64::from(u32::MAX)) as u32
    }
}

/// `round_half_away(offset / step)` for quotients below 2¹⁹ in magnitude, given `inverse =
/// 1 / step` (see [`Grid::quantize`]).
fn nearest_steps(offset: f64, step: f64, inverse: f64) -> i64 {
    let quotient = offset * inverse;
    let fraction = quotient - (quotient as i64) as f64;
    if (fraction.abs() - 0.5).abs() <= NEAR_HALF_STEP {
        round_half_away(offset / step)
    } else {
        round_half_away(quotient)
    }
}

/// `x.round() as i64` (halves away from zero; saturating, NaN to 0) without the libm call
/// that `f64::round` costs on the x86-64 baseline, which has no rounding instruction: the
/// builder snaps every vertex and the writer quantises every node through this. The
/// truncating conversion is one instruction, and below 2⁵² in magnitude the fraction
/// `x − trunc(x)` is exactly representable, so comparing it with ±½ decides exactly as
/// `round` does. From 2⁵² on every `f64` is an integer (or infinite or NaN), and the
/// saturating conversion alone gives `round`'s result.
pub(crate) fn round_half_away(x: f64) -> i64 {
    const INTEGRAL_FROM: f64 = 4_503_599_627_370_496.0; // 2⁵²
    // NaN converts to 0, as `round`'s NaN does.
    if x.abs() >= INTEGRAL_FROM || x.is_nan() {
        return x as i64;
    }
    let truncated = x as i64;
    let fraction = x - truncated as f64;
    if fraction >= 0.5 {
        truncated + 1
    } else if fraction <= -0.5 {
        truncated - 1
    } else {
        truncated
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`Grid::quantize`] as the definition reads: a division per coordinate.
    fn quantize_by_division(grid: &Grid, p: [f32; 3]) -> [u32; 3] {
        [0, 1, 2].map(|k| {
            let steps = round_half_away(
                (f64::from(p[k]) - f64::from(grid.origin[k])) / f64::from(grid.step),
            );
            steps.clamp(0, i64::from(GRID_STEPS)) as u32
        })
    }

    #[test]
    fn nearest_steps_divides_near_half_steps() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut multiplication_wrong = 0;
        for _ in 0..100_000 {
            let step = f64::from((10f64.powf(next() * 8.0 - 6.0)) as f32);
            let inverse = 1.0 / step;
            // A half step, nudged by a few ulps either way.
            let half = (next() * f64::from(2 * GRID_STEPS)).trunc() - f64::from(GRID_STEPS) + 0.5;
            let mut offset = half * step;
            for _ in 0..(next() * 8.0) as u32 {
                offset = if next() < 0.5 {
                    offset.next_up()
                } else {
                    offset.next_down()
                };
            }
            let by_division = round_half_away(offset / step);
            assert_eq!(
                nearest_steps(offset, step, inverse),
                by_division,
                "{offset} / {step}"
            );
            multiplication_wrong += usize::from(round_half_away(offset * inverse) != by_division);
        }
        // The cases the division is there for occur (so this test can fail).
        assert!(multiplication_wrong > 0);
    }

    #[test]
    fn quantize_is_the_division_on_and_off_the_grid() {
        let grid = Grid::for_bounds([-1.0, 2.0, 3.5], [0.25, 7.0, 4.0]);
        let mut state = 7u32;
        for _ in 0..100_000 {
            let p = [0, 1, 2].map(|_| {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (f64::from(state) / f64::from(u32::MAX) * 12.0 - 3.0) as f32
            });
            assert_eq!(grid.quantize(p), quantize_by_division(&grid, p));
        }
        for p in [
            [f32::NAN; 3],
            [f32::INFINITY; 3],
            [f32::NEG_INFINITY; 3],
            [f32::MAX; 3],
        ] {
            assert_eq!(grid.quantize(p), quantize_by_division(&grid, p));
        }
    }

    #[test]
    fn round_half_away_is_round() {
        let mut values = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            0.49999999999999994,
            -0.49999999999999994,
            1e15 + 0.5,
            4503599627370495.5,
            4503599627370496.0,
            9.3e18,
            -9.3e18,
            1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            262143.5,
            262144.49,
        ];
        let mut seed = 1u64;
        for _ in 0..100_000 {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let x = (seed >> 11) as f64 / (1u64 << 53) as f64;
            values.push((x - 0.5) * 1e6);
            values.push(((seed >> 20) % 1000) as f64 * 0.5 - 250.0);
        }
        for x in values {
            assert_eq!(round_half_away(x), x.round() as i64, "{x}");
        }
    }
}
