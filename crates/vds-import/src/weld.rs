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
        parts,
        short_faces_dropped,
        warnings,
        spill: _,
    } = soup;
    let input_vertices = positions.len() as u64;
    let input_triangles = triangles.len() as u64;
    let representative = match weld {
        Weld::Exact => exact_representatives(&positions),
        Weld::Relative(fraction) => {
            let diagonal = diagonal(&positions);
            let tolerance = f64::from(fraction) * diagonal;
            // A tolerance below 2⁻⁴⁰ of the diagonal is exact welding in effect (f32 positions
            // hold 24 bits), and it would make grid cell indices overflow.
            if tolerance > 0.0 && diagonal / tolerance <= (1u64 << 40) as f64 {
                tolerance_representatives(&positions, tolerance)
            } else {
                exact_representatives(&positions)
            }
        }
    };
    let distinct = representative
        .par_iter()
        .enumerate()
        .filter(|&(i, &r)| i as u32 == r)
        .count() as u64;

    // Which representatives a triangle that stays (no repeated corner once welded) uses,
    // marked in parallel (every mark writes the same value, so the order does not matter).
    let corners = |t: &[u32; 3]| t.map(|v| representative[v as usize]);
    let stays = |[a, b, c]: [u32; 3]| a != b && b != c && a != c;
    let used: Vec<AtomicU32> = (0..positions.len())
        .into_par_iter()
        .map(|_| AtomicU32::new(0))
        .collect();
    let degenerate: u64 = triangles
        .par_iter()
        .map(|t| {
            let corners = corners(t);
            if !stays(corners) {
                return 1;
            }
            for v in corners {
                used[v as usize].store(1, Ordering::Relaxed);
            }
            0
        })
        .sum();

    // New indices for the used representatives, in input order, with the positions compacted
    // in place (one pass: each position moves down, never up); then every vertex's final
    // index through its representative.
    let mut new_index: Vec<u32> = used.into_iter().map(AtomicU32::into_inner).collect();
    let mut count = 0usize;
    for old in 0..new_index.len() {
        if new_index[old] != 0 {
            new_index[old] = count as u32;
            positions[count] = positions[old];
            count += 1;
        }
    }
    positions.truncate(count);
    positions.shrink_to_fit();
    let mut final_index = representative;
    final_index
        .par_iter_mut()
        .for_each(|r| *r = new_index[*r as usize]);
    drop(new_index);

    // Rewrite the corners in place (the soup's arrays become the scene's, so no second copy
    // of the mesh is touched); only when a triangle goes do the rest move, one thread.
    if degenerate == 0 {
        triangles
            .par_iter_mut()
            .for_each(|t| *t = t.map(|v| final_index[v as usize]));
    } else {
        // The test on final indices drops the same triangles as the test on representatives:
        // a triangle with distinct representatives marked them all used, and used ones get
        // distinct final indices; one with a repeated representative keeps the repeat.
        let mut kept = 0;
        for i in 0..triangles.len() {
            let corners = triangles[i].map(|v| final_index[v as usize]);
            if stays(corners) {
                triangles[kept] = corners;
                triangle_parts[kept] = triangle_parts[i];
                kept += 1;
            }
        }
        triangles.truncate(kept);
        triangle_parts.truncate(kept);
    }
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
        parts,
        warnings,
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

/// A multiplicative hash of a position's 96 bits (`-0.0` hashed as `0.0`, so that positions
/// the exact weld joins hash alike); its top bits pick a bucket.
pub(crate) fn position_hash(p: &[f32; 3]) -> u64 {
    let [x, y, z] = p.map(|c| u64::from((c + 0.0).to_bits()));
    let h =
        (x << 32 | y).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ z.wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h.wrapping_mul(0x1656_67B1_9E37_79F9)
}

/// For each vertex, the lowest index with bit-identical position.
///
/// Each vertex becomes a 128-bit key: x, y and z bits and the index (`+ 0.0` turns -0.0 into
/// 0.0 so both weld; every other value keeps its bits). The keys are scattered, stably, into
/// buckets by a hash of the position (equal positions share a bucket), a few thousand keys
/// each, and the buckets are resolved in parallel, each with a hash table that stays in
/// cache. (Sorting all keys at once went to memory at every level: 0.13 s of the 10 M
/// scene's 0.25 s weld; sorting each bucket, 0.05 s; the tables do without the sorts' log
/// factor.) Which bucket a key lands in does not change the groups or their lowest index, so
/// the result does not depend on the thread count.
pub(crate) fn exact_representatives(positions: &[[f32; 3]]) -> Vec<u32> {
    let bits = |p: &[f32; 3]| p.map(|c| (c + 0.0).to_bits());
    let key = |i: usize, p: &[f32; 3]| {
        let [x, y, z] = bits(p).map(u128::from);
        x << 96 | y << 64 | z << 32 | i as u128
    };
    // About 4096 keys per bucket, 2 to 2¹² buckets (at least one bit: the bucket is the
    // hash shifted right by 64 minus the bits).
    let bucket_bits = (positions.len() / 4096).max(2).ilog2().min(12);
    let bucket = |p: &[f32; 3]| (position_hash(p) >> (64 - bucket_bits)) as usize;
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
    // Each bucket's keys are in index order (chunks scatter in order, each in order), so the
    // first key of a position seen in a bucket has its lowest index: a small open-addressing
    // table per bucket, in cache, finds it for every later one.
    let representative: Vec<AtomicU32> = (0..positions.len())
        .into_par_iter()
        .map(|_| AtomicU32::new(0))
        .collect();
    let mut bucket_slices: Vec<&[u128]> = Vec::with_capacity(buckets);
    let mut rest: &[u128] = &keyed;
    for &size in &sizes {
        let (head, tail) = rest.split_at(size);
        bucket_slices.push(head);
        rest = tail;
    }
    let position = |key: u128| key >> 32;
    let index = |key: u128| key as u32;
    bucket_slices
        .into_par_iter()
        .for_each_init(Vec::new, |table: &mut Vec<u32>, keys| {
            // Slots hold 1 + a key's place in `keys`; 0 is empty. At most half full.
            let slots = (2 * keys.len()).next_power_of_two().max(16);
            table.clear();
            table.resize(slots, 0);
            let mask = slots - 1;
            for (at, &key) in keys.iter().enumerate() {
                let p = position(key);
                // Other bits of the position than those that chose the bucket.
                let h = (p as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                    ^ ((p >> 64) as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
                let mut slot = (h >> 20) as usize & mask;
                let first = loop {
                    match table[slot] {
                        0 => {
                            table[slot] = at as u32 + 1;
                            break key;
                        }
                        seen if position(keys[seen as usize - 1]) == p => {
                            break keys[seen as usize - 1];
                        }
                        _ => slot = (slot + 1) & mask,
                    }
                };
                // Every index is written exactly once, by the bucket that holds it.
                representative[index(key) as usize].store(index(first), Ordering::Relaxed);
            }
        });
    representative
        .into_iter()
        .map(AtomicU32::into_inner)
        .collect()
}

/// For each vertex, the lowest index of its group of vertices chained within `tolerance`.
fn tolerance_representatives(positions: &[[f32; 3]], tolerance: f64) -> Vec<u32> {
    // Cells count from the bounding box's corner, so a cell index is at most the extent over
    // the tolerance (1 / the relative tolerance), not a coordinate over it: a small part far
    // from the origin would otherwise overflow `i64`. Neighbour offsets saturate for
    // tolerances below 2⁻⁶³ of the extent, where the distance test still decides.
    let mut low = [f64::INFINITY; 3];
    for p in positions {
        for k in 0..3 {
            low[k] = low[k].min(f64::from(p[k]));
        }
    }
    let cell_of = |p: &[f32; 3]| {
        let mut cell = [0i64; 3];
        for k in 0..3 {
            cell[k] = ((f64::from(p[k]) - low[k]) / tolerance).floor() as i64;
        }
        cell
    };
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
                    let neighbour = [
                        cell[0].saturating_add(dx),
                        cell[1].saturating_add(dy),
                        cell[2].saturating_add(dz),
                    ];
                    let Some(others) = grid.get(&neighbour) else {
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

    /// One step of a xorshift generator: the next state, which is also the value drawn.
    fn xorshift(seed: &mut u64) -> u64 {
        *seed ^= *seed << 13;
        *seed ^= *seed >> 7;
        *seed ^= *seed << 17;
        *seed
    }

    /// Positions with many exact repeats (and `-0.0` beside `0.0`), over several chunks and
    /// buckets.
    fn repeating_positions(n: usize) -> Vec<[f32; 3]> {
        let mut seed = 0x2545_F491_4F6C_DD1Du64;
        (0..n)
            .map(|_| {
                xorshift(&mut seed);
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

    /// The exact weld, one step at a time as the scene's definition reads: each position
    /// becomes its lowest index; triangles with a repeated corner go; the representatives
    /// still used are numbered in input order.
    fn reference_weld(soup: &MeshSoup) -> (Vec<[f32; 3]>, Vec<[u32; 3]>, Vec<u32>) {
        let mut first: FxHashMap<[u32; 3], u32> = FxHashMap::default();
        let representative: Vec<u32> = (0..soup.positions.len())
            .map(|i| {
                let bits = soup.positions[i].map(|c| (c + 0.0).to_bits());
                *first.entry(bits).or_insert(i as u32)
            })
            .collect();
        let kept: Vec<([u32; 3], u32)> = soup
            .triangles
            .iter()
            .zip(&soup.triangle_parts)
            .map(|(t, &part)| (t.map(|v| representative[v as usize]), part))
            .filter(|([a, b, c], _)| a != b && b != c && a != c)
            .collect();
        let mut used = vec![false; soup.positions.len()];
        for (t, _) in &kept {
            for &v in t {
                used[v as usize] = true;
            }
        }
        let mut new_index = vec![u32::MAX; soup.positions.len()];
        let mut positions = Vec::new();
        for (old, _) in used.iter().enumerate().filter(|&(_, &u)| u) {
            new_index[old] = positions.len() as u32;
            positions.push(soup.positions[old]);
        }
        let triangles = kept
            .iter()
            .map(|(t, _)| t.map(|v| new_index[v as usize]))
            .collect();
        let parts = kept.iter().map(|&(_, part)| part).collect();
        (positions, triangles, parts)
    }

    #[test]
    fn weld_matches_the_reference_with_repeats_degenerates_and_unused_vertices() {
        let positions = repeating_positions(2 * WELD_CHUNK + 77);
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move |n: usize| (xorshift(&mut seed) % n as u64) as u32;
        // Corners drawn from the first half only, so the second half's vertices go unused;
        // some triangles repeat an index, more collapse when welded.
        let half = positions.len() / 2;
        let triangles: Vec<[u32; 3]> = (0..100_000)
            .map(|k| {
                let a = next(half);
                let b = if k % 97 == 0 { a } else { next(half) };
                [a, b, next(half)]
            })
            .collect();
        let triangle_parts: Vec<u32> = (0..triangles.len() as u32).map(|k| k % 7).collect();
        let soup = MeshSoup {
            positions,
            triangles,
            triangle_parts,
            part_names: (0..7).map(|k| format!("part {k}")).collect(),
            parts: vec![Default::default(); 7],
            short_faces_dropped: 0,
            warnings: Vec::new(),
            spill: Default::default(),
        };
        let (positions, triangles, parts) = reference_weld(&soup);
        assert!(
            triangles.len() < soup.triangles.len(),
            "the test needs degenerates"
        );
        for threads in [1, 2] {
            let scene = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| weld(soup.clone(), Weld::Exact));
            assert_eq!(scene.positions, positions);
            assert_eq!(scene.triangles, triangles);
            assert_eq!(scene.triangle_parts, parts);
            let dropped = soup.triangles.len() - triangles.len();
            assert_eq!(scene.stats.degenerate_triangles_dropped, dropped as u64);
        }
        // And with nothing to drop: every triangle's corners distinct once welded.
        let clean = MeshSoup {
            triangles: triangles.clone(),
            triangle_parts: parts.clone(),
            positions: positions.clone(),
            ..soup.clone()
        };
        let scene = weld(clean, Weld::Exact);
        assert_eq!((scene.positions, scene.triangles), (positions, triangles));
    }
}
