//! Welding: turns a triangle soup into an indexed [`Scene`] by joining vertices at the same
//! position (exactly, or within a tolerance), dropping triangles that welding made
//! degenerate and vertices no triangle uses.
//!
//! The exact weld sorts `(position bits, index)` pairs within buckets of a position hash, so
//! it runs in parallel and its result does not depend on the thread count: every group is
//! represented by its lowest index, and surviving vertices keep their input order.

use std::sync::atomic::{AtomicU32, Ordering};

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

    // Remap corners to representatives (in parallel) and drop triangles with a repeated
    // corner, in place: the soup's arrays become the scene's, so no second copy of the mesh
    // is ever touched.
    triangles
        .par_iter_mut()
        .for_each(|t| *t = t.map(|v| representative[v as usize]));
    let mut kept = 0;
    for i in 0..triangles.len() {
        let [a, b, c] = triangles[i];
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

/// The least number of positions per parallel chunk of the exact weld's counting and
/// scattering passes.
const WELD_CHUNK: usize = 1 << 16;

/// Positions per chunk for `n` positions: at least [`WELD_CHUNK`], and few enough chunks
/// (about 64) that the chunks' per-bucket counts and pieces stay small however large the
/// input.
fn weld_chunk(n: usize) -> usize {
    (n / 64).max(WELD_CHUNK)
}

/// For each vertex, the lowest index with bit-identical position.
///
/// Each vertex becomes a 128-bit key: x, y and z bits and the index, from the most
/// significant word down, so keys order like (position, index) and equal positions are
/// adjacent once sorted (`+ 0.0` turns -0.0 into 0.0 so both weld; every other value keeps
/// its bits). Instead of one sort of all keys, the keys are first scattered into buckets by
/// a hash of the position (equal positions share a bucket), a few thousand keys each, and
/// the buckets are sorted in parallel: each sort then runs in cache, where one sort of the
/// 10 M scene's 88 MB of keys went to memory at every level (0.13 s of its 0.25 s weld).
/// Which bucket a key lands in does not change the groups or their lowest index, so the
/// result does not depend on the thread count.
fn exact_representatives(positions: &[[f32; 3]]) -> Vec<u32> {
    let bits = |p: &[f32; 3]| p.map(|c| (c + 0.0).to_bits());
    let key = |i: usize, p: &[f32; 3]| {
        let [x, y, z] = bits(p).map(u128::from);
        x << 96 | y << 64 | z << 32 | i as u128
    };
    // About 4096 keys per bucket, 2 to 2¹² buckets (at least one bit: the bucket is the
    // hash shifted right by 64 minus the bits).
    let bucket_bits = (positions.len() / 4096).max(2).ilog2().min(12);
    let bucket = |p: &[f32; 3]| {
        let [x, y, z] = bits(p).map(u64::from);
        // A multiplicative hash of the 96 position bits; its top bits pick the bucket.
        let h = (x << 32 | y).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ z.wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        (h.wrapping_mul(0x1656_67B1_9E37_79F9) >> (64 - bucket_bits)) as usize
    };
    let buckets = 1usize << bucket_bits;
    let chunk_size = weld_chunk(positions.len());
    // Counting sort into buckets: each chunk's count per bucket, then each chunk scatters in
    // parallel into its own piece of each bucket.
    let chunk_counts: Vec<Vec<u32>> = positions
        .par_chunks(chunk_size)
        .map(|chunk| {
            let mut counts = vec![0u32; buckets];
            for p in chunk {
                counts[bucket(p)] += 1;
            }
            counts
        })
        .collect();
    let sizes: Vec<usize> = (0..buckets)
        .map(|b| chunk_counts.iter().map(|c| c[b] as usize).sum())
        .collect();
    let mut keyed = vec![0u128; positions.len()];
    // Each bucket's keys, cut into one piece per chunk in chunk order.
    let mut pieces: Vec<Vec<&mut [u128]>> = chunk_counts
        .iter()
        .map(|_| Vec::with_capacity(buckets))
        .collect();
    let mut rest: &mut [u128] = &mut keyed;
    for b in 0..buckets {
        for (chunk, piece) in chunk_counts.iter().zip(&mut pieces) {
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(chunk[b] as usize);
            piece.push(head);
            rest = tail;
        }
    }
    positions
        .par_chunks(chunk_size)
        .zip(pieces)
        .enumerate()
        .for_each(|(c, (chunk, mut pieces))| {
            let mut filled = vec![0usize; buckets];
            for (k, p) in chunk.iter().enumerate() {
                let b = bucket(p);
                pieces[b][filled[b]] = key(c * chunk_size + k, p);
                filled[b] += 1;
            }
        });
    // Sort each bucket; in each run of equal positions the first key has the lowest index.
    let representative: Vec<AtomicU32> = (0..positions.len())
        .into_par_iter()
        .map(|_| AtomicU32::new(0))
        .collect();
    let mut bucket_slices: Vec<&mut [u128]> = Vec::with_capacity(buckets);
    let mut rest: &mut [u128] = &mut keyed;
    for &size in &sizes {
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(size);
        bucket_slices.push(head);
        rest = tail;
    }
    let position = |key: u128| key >> 32;
    let index = |key: u128| key as u32;
    bucket_slices.into_par_iter().for_each(|keys| {
        keys.sort_unstable();
        let mut group_start = 0;
        for i in 0..keys.len() {
            if position(keys[i]) != position(keys[group_start]) {
                group_start = i;
            }
            // Every index is written exactly once, by the bucket that holds it.
            representative[index(keys[i]) as usize]
                .store(index(keys[group_start]), Ordering::Relaxed);
        }
    });
    representative
        .into_iter()
        .map(AtomicU32::into_inner)
        .collect()
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Positions with many exact repeats (and `-0.0` beside `0.0`), over several chunks and
    /// buckets.
    fn repeating_positions(n: usize) -> Vec<[f32; 3]> {
        let mut seed = 0x2545_F491_4F6C_DD1Du64;
        (0..n)
            .map(|_| {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                let pick = (seed % 50_000) as f32;
                let sign = if seed >> 63 == 0 { 1.0 } else { -1.0 };
                [pick * 0.25, (pick * 0.5).floor(), sign * 0.0]
            })
            .collect()
    }

    #[test]
    fn exact_representatives_are_the_lowest_index_of_each_position() {
        let positions = repeating_positions(3 * WELD_CHUNK + 123);
        let mut first: FxHashMap<[u32; 3], u32> = FxHashMap::default();
        let expected: Vec<u32> = positions
            .iter()
            .enumerate()
            .map(|(i, p)| {
                *first
                    .entry(p.map(|c| (c + 0.0).to_bits()))
                    .or_insert(i as u32)
            })
            .collect();
        assert!(first.len() < positions.len() / 2, "the test needs repeats");
        assert_eq!(exact_representatives(&positions), expected);
        let one_thread = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| exact_representatives(&positions));
        assert_eq!(one_thread, expected);
        assert_eq!(exact_representatives(&positions[..5]), expected[..5]);
        assert!(exact_representatives(&[]).is_empty());
    }
}
