//! Surface-to-surface distance for the fidelity comparison (as Metro does it): points spread
//! over one surface by area, each measured to the nearest point of the other surface.
//!
//! Nearest-triangle queries use a uniform grid over both meshes' bounds, every triangle
//! listed in each cell its bounding box overlaps, searched in growing shells of cells until
//! no unvisited cell can hold anything nearer. Hand-written because it is forty lines and
//! only this benchmark needs it.

use glam::DVec3;
use rayon::prelude::*;

/// Closest distance from `p` to triangle `abc` (Ericson, Real-Time Collision Detection
/// §5.1.5).
fn point_triangle_distance(p: DVec3, [a, b, c]: [DVec3; 3]) -> f64 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return p.distance(a);
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return p.distance(b);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return p.distance(a + ab * (d1 / (d1 - d3)));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return p.distance(c);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return p.distance(a + ac * (d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return p.distance(b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
    }
    let denominator = 1.0 / (va + vb + vc);
    p.distance(a + ab * (vb * denominator) + ac * (vc * denominator))
}

/// A triangle mesh prepared for nearest-point queries.
pub struct NearestTriangle {
    triangles: Vec<[DVec3; 3]>,
    origin: DVec3,
    cell: f64,
    dims: [usize; 3],
    cell_start: Vec<u32>,
    cell_triangles: Vec<u32>,
}

impl NearestTriangle {
    /// Indexes `triangles`; queries must lie inside `min..max`, which must hold the mesh.
    pub fn new(triangles: Vec<[DVec3; 3]>, min: DVec3, max: DVec3) -> NearestTriangle {
        let extent = (max - min).max(DVec3::splat(1e-12));
        // About two cells per triangle.
        let cell = (extent.x * extent.y * extent.z / (2.0 * triangles.len().max(1) as f64))
            .cbrt()
            .max(extent.max_element() / 512.0);
        let dims = [extent.x, extent.y, extent.z].map(|e| ((e / cell).ceil() as usize).max(1));
        let cell_of = |p: DVec3| {
            let q = ((p - min) / cell).floor();
            [q.x, q.y, q.z]
                .iter()
                .zip(dims)
                .map(|(&v, d)| (v.max(0.0) as usize).min(d - 1))
                .collect::<Vec<_>>()
        };
        let ranges: Vec<[std::ops::RangeInclusive<usize>; 3]> = triangles
            .iter()
            .map(|t| {
                let lo = cell_of(t[0].min(t[1]).min(t[2]));
                let hi = cell_of(t[0].max(t[1]).max(t[2]));
                [lo[0]..=hi[0], lo[1]..=hi[1], lo[2]..=hi[2]]
            })
            .collect();
        let index = |x: usize, y: usize, z: usize| (z * dims[1] + y) * dims[0] + x;
        let mut counts = vec![0u32; dims[0] * dims[1] * dims[2] + 1];
        let each = |f: &mut dyn FnMut(usize, u32)| {
            for (t, [rx, ry, rz]) in ranges.iter().enumerate() {
                for z in rz.clone() {
                    for y in ry.clone() {
                        for x in rx.clone() {
                            f(index(x, y, z), t as u32);
                        }
                    }
                }
            }
        };
        each(&mut |c, _| counts[c + 1] += 1);
        for k in 1..counts.len() {
            counts[k] += counts[k - 1];
        }
        let mut fill = counts.clone();
        let mut cell_triangles = vec![0u32; *counts.last().unwrap() as usize];
        each(&mut |c, t| {
            cell_triangles[fill[c] as usize] = t;
            fill[c] += 1;
        });
        NearestTriangle {
            triangles,
            origin: min,
            cell,
            dims,
            cell_start: counts,
            cell_triangles,
        }
    }

    /// Distance from `p` to the nearest triangle.
    pub fn distance(&self, p: DVec3) -> f64 {
        let q = ((p - self.origin) / self.cell).floor();
        let centre = [q.x, q.y, q.z]
            .iter()
            .zip(self.dims)
            .map(|(&v, d)| (v.max(0.0) as i64).min(d as i64 - 1))
            .collect::<Vec<_>>();
        let mut best = f64::INFINITY;
        let largest = *self.dims.iter().max().unwrap() as i64;
        for r in 0..=largest {
            for z in centre[2] - r..=centre[2] + r {
                for y in centre[1] - r..=centre[1] + r {
                    for x in centre[0] - r..=centre[0] + r {
                        let on_shell = (x - centre[0]).abs() == r
                            || (y - centre[1]).abs() == r
                            || (z - centre[2]).abs() == r;
                        let inside = [x, y, z]
                            .iter()
                            .zip(self.dims)
                            .all(|(&v, d)| v >= 0 && v < d as i64);
                        if !on_shell || !inside {
                            continue;
                        }
                        let c =
                            ((z as usize * self.dims[1]) + y as usize) * self.dims[0] + x as usize;
                        let range = self.cell_start[c] as usize..self.cell_start[c + 1] as usize;
                        for &t in &self.cell_triangles[range] {
                            best = best.min(point_triangle_distance(p, self.triangles[t as usize]));
                        }
                    }
                }
            }
            // Every unvisited cell is at least `r` whole cells away from `p`'s cell.
            if best <= r as f64 * self.cell {
                break;
            }
        }
        best
    }
}

/// About `count` points spread over the triangles by area (deterministic: a low-discrepancy
/// sequence folded into each triangle).
pub fn surface_samples(triangles: &[[DVec3; 3]], count: usize) -> Vec<DVec3> {
    let areas: Vec<f64> = triangles
        .iter()
        .map(|t| (t[1] - t[0]).cross(t[2] - t[0]).length() / 2.0)
        .collect();
    let total: f64 = areas.iter().sum();
    let mut samples = Vec::with_capacity(count + triangles.len());
    let mut cumulative = 0.0;
    let mut emitted = 0usize;
    let mut k = 0u64;
    for (t, area) in triangles.iter().zip(&areas) {
        cumulative += area;
        let until = (cumulative / total * count as f64).round() as usize;
        while emitted < until {
            // R2 sequence (the plastic number's low-discrepancy pair).
            k += 1;
            let mut u = (0.754_877_666_246_692_7 * k as f64).fract();
            let mut v = (0.569_840_290_998_053_2 * k as f64).fract();
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            samples.push(t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v);
            emitted += 1;
        }
    }
    samples
}

/// Mean and largest distance from `samples` to the mesh, in one pass of nearest-point
/// queries.
pub fn distances(samples: &[DVec3], mesh: &NearestTriangle) -> (f64, f64) {
    let (sum, max) = samples
        .par_iter()
        .map(|&p| {
            let d = mesh.distance(p);
            (d, d)
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1.max(b.1)));
    (sum / samples.len().max(1) as f64, max)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (SplitMix64).
    fn unit(state: &mut u64) -> f64 {
        *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn grid_search_matches_exhaustive_search() {
        let mut state = 1;
        let mut point = || DVec3::new(unit(&mut state), unit(&mut state), unit(&mut state) * 0.2);
        let triangles: Vec<[DVec3; 3]> = (0..300)
            .map(|_| {
                let a = point();
                [a, a + (point() - a) * 0.1, a + (point() - a) * 0.1]
            })
            .collect();
        let grid = NearestTriangle::new(triangles.clone(), DVec3::ZERO, DVec3::ONE);
        for _ in 0..500 {
            let p = DVec3::new(unit(&mut state), unit(&mut state), unit(&mut state));
            let exhaustive = triangles
                .iter()
                .map(|&t| point_triangle_distance(p, t))
                .fold(f64::INFINITY, f64::min);
            assert_eq!(grid.distance(p), exhaustive);
        }
    }

    #[test]
    fn a_mesh_is_at_distance_zero_from_itself() {
        let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let mesh = NearestTriangle::new(vec![t], DVec3::ZERO, DVec3::ONE);
        let samples = surface_samples(&[t], 1000);
        assert_eq!(samples.len(), 1000);
        assert!(distances(&samples, &mesh).0 < 1e-12);
        assert!((mesh.distance(DVec3::new(0.2, 0.2, 0.5)) - 0.5).abs() < 1e-12);
    }
}
