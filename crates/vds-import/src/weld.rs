//! Welding: turns a triangle soup into an indexed [`Scene`] by joining vertices at the same
//! position (exactly, or within a tolerance), dropping triangles that welding made
//! degenerate and vertices no triangle uses.
//!
//! The exact weld sorts `(position bits, index)` pairs, so it runs in parallel and its result
//! does not depend on the thread count: every group is represented by its lowest index, and
//! surviving vertices keep their input order.

use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::soup::MeshSoup;
use crate::{ImportStats, Scene};

/// How vertices are joined.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Weld {
    /// Join vertices whose positions are bit-for-bit equal (`-0.0` equals `0.0`).
    #[default]
    Exact,
    /// Join vertices closer than this fraction of the bounding-box diagonal. Chains of close
    /// vertices join transitively; each group takes the position of its first vertex.
    Relative(f32),
}

/// Welds `soup` into a scene.
pub fn weld(soup: MeshSoup, weld: Weld) -> Scene {
    let MeshSoup {
        mut positions,
        mut triangles,
        mut triangle_parts,
        part_names,
        short_faces_dropped,
    } = soup;
    let input_vertices = positions.len() as u64;
    let input_triangles = triangles.len() as u64;
    let representative = match weld {
        Weld::Exact => exact_representatives(&positions),
        Weld::Relative(fraction) => {
            let tolerance = f64::from(fraction) * diagonal(&positions);
            if tolerance > 0.0 {
                tolerance_representatives(&positions, tolerance)
            } else {
                exact_representatives(&positions)
            }
        }
    };
    let distinct = representative
        .iter()
        .enumerate()
        .filter(|&(i, &r)| i as u32 == r)
        .count() as u64;

    // Remap corners to representatives and drop triangles with a repeated corner, in place:
    // the soup's arrays become the scene's, so no second copy of the mesh is ever touched.
    let mut kept = 0;
    for i in 0..triangles.len() {
        let [a, b, c] = triangles[i].map(|v| representative[v as usize]);
        if a != b && b != c && a != c {
            triangles[kept] = [a, b, c];
            triangle_parts[kept] = triangle_parts[i];
            kept += 1;
        }
    }
    triangles.truncate(kept);
    triangle_parts.truncate(kept);
    let degenerate = input_triangles - kept as u64;

    // Keep referenced representatives in input order, compacting positions in place.
    const UNUSED: u32 = u32::MAX;
    let mut new_index = representative;
    new_index.fill(UNUSED);
    for t in &triangles {
        for &v in t {
            new_index[v as usize] = 0;
        }
    }
    let mut count = 0usize;
    for old in 0..new_index.len() {
        if new_index[old] != UNUSED {
            new_index[old] = count as u32;
            positions[count] = positions[old];
            count += 1;
        }
    }
    positions.truncate(count);
    positions.shrink_to_fit();
    triangles
        .par_iter_mut()
        .for_each(|t| *t = t.map(|v| new_index[v as usize]));
    Scene {
        stats: ImportStats {
            input_vertices,
            input_triangles,
            welded_vertices: input_vertices - distinct,
            degenerate_triangles_dropped: degenerate,
            short_faces_dropped,
            unreferenced_vertices_dropped: distinct - count as u64,
        },
        positions,
        triangles,
        triangle_parts,
        part_names,
    }
}

/// The length of the bounding box's diagonal.
fn diagonal(positions: &[[f32; 3]]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in positions {
        for k in 0..3 {
            lo[k] = lo[k].min(f64::from(p[k]));
            hi[k] = hi[k].max(f64::from(p[k]));
        }
    }
    if positions.is_empty() {
        return 0.0;
    }
    (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt()
}

/// For each vertex, the lowest index with bit-identical position.
fn exact_representatives(positions: &[[f32; 3]]) -> Vec<u32> {
    // x, y and z bits and the index, from the most significant word down, sort like
    // (position, index) in one 128-bit integer, whose comparison is two machine words where
    // a `[u32; 4]` compares element by element. `+ 0.0` turns -0.0 into 0.0 so both weld;
    // every other value keeps its bits.
    let mut keyed: Vec<u128> = positions
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let [x, y, z] = p.map(|c| u128::from((c + 0.0).to_bits()));
            x << 96 | y << 64 | z << 32 | i as u128
        })
        .collect();
    keyed.par_sort_unstable();
    let position = |key: u128| key >> 32;
    let index = |key: u128| key as u32;
    let mut representative = vec![0u32; positions.len()];
    let mut group_start = 0;
    for i in 0..keyed.len() {
        if position(keyed[i]) != position(keyed[group_start]) {
            group_start = i;
        }
        representative[index(keyed[i]) as usize] = index(keyed[group_start]);
    }
    representative
}

/// For each vertex, the lowest index of its group of vertices chained within `tolerance`.
fn tolerance_representatives(positions: &[[f32; 3]], tolerance: f64) -> Vec<u32> {
    let cell_of = |p: &[f32; 3]| p.map(|c| (f64::from(c) / tolerance).floor() as i64);
    let mut parent: Vec<u32> = (0..positions.len() as u32).collect();
    fn root(parent: &mut [u32], mut v: u32) -> u32 {
        while parent[v as usize] != v {
            let up = parent[parent[v as usize] as usize];
            parent[v as usize] = up;
            v = up;
        }
        v
    }
    let mut grid: FxHashMap<[i64; 3], Vec<u32>> = FxHashMap::default();
    let squared = tolerance * tolerance;
    for (i, p) in positions.iter().enumerate() {
        let cell = cell_of(p);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(others) = grid.get(&[cell[0] + dx, cell[1] + dy, cell[2] + dz]) else {
                        continue;
                    };
                    for &j in others {
                        let q = positions[j as usize];
                        let d2: f64 = (0..3)
                            .map(|k| (f64::from(p[k]) - f64::from(q[k])).powi(2))
                            .sum();
                        if d2 <= squared {
                            let (a, b) = (root(&mut parent, i as u32), root(&mut parent, j));
                            // The lower index becomes the root, so groups keep their first vertex.
                            let (low, high) = (a.min(b), a.max(b));
                            parent[high as usize] = low;
                        }
                    }
                }
            }
        }
        grid.entry(cell).or_default().push(i as u32);
    }
    (0..positions.len() as u32)
        .map(|v| root(&mut parent, v))
        .collect()
}
