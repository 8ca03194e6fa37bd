//! A shard's own numbering of the vertices its triangles use: its input lists those vertices
//! in global id order, and each corner's global id becomes its vertex's place in that list,
//! so local numbers follow global order.
//!
//! Two ways give the same numbers. The reference binary-searches the list for each corner
//! (about twenty steps a corner). Where the plan's vertex count is small enough, a bit per
//! plan vertex marks the listed ids and each 64-bit word keeps the rank of its first bit, so a
//! corner's number is a lookup and a popcount (the sort and search took 12 % of a shard's time
//! on the 10 M scene cut in four). The bits are used only where they take no more memory than
//! the triangles do (a plan of at most 64 vertices per triangle of the shard), so a shard of a
//! huge model cut fine still searches.

use rayon::prelude::*;

/// Why a shard's corners and its list of vertices do not fit together.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Mismatch {
    /// A corner's vertex id at or past the plan's vertex count.
    PastTheCount,
    /// A corner whose vertex the list lacks.
    Unlisted,
    /// A listed vertex no corner uses.
    Unused,
}

/// Replaces each corner's global vertex id (below `vertex_count`) with its place in `listed`
/// (strictly increasing ids, below `vertex_count` too), which must hold the ids the corners
/// use and no others.
pub(crate) fn number_corners(
    triangles: &mut [[u32; 3]],
    listed: &[u32],
    vertex_count: u32,
) -> Result<(), Mismatch> {
    debug_assert!(listed.windows(2).all(|w| w[0] < w[1]));
    if listed.last().is_some_and(|&v| v >= vertex_count)
        || triangles.iter().flatten().any(|&v| v >= vertex_count)
    {
        return Err(Mismatch::PastTheCount);
    }
    let words = (vertex_count as usize).div_ceil(64);
    // Bits and ranks take 12 bytes a word, the triangles 12 bytes each.
    if words <= triangles.len() {
        by_bits(triangles, listed, words)?;
    } else {
        by_search(triangles, listed)?;
    }
    every_one_used(triangles, listed.len())
}

/// [`number_corners`] with a bit per vertex.
fn by_bits(triangles: &mut [[u32; 3]], listed: &[u32], words: usize) -> Result<(), Mismatch> {
    let mut bits = vec![0u64; words];
    for &v in listed {
        bits[v as usize / 64] |= 1u64 << (v % 64);
    }
    let mut first_rank = Vec::with_capacity(words);
    let mut count = 0u32;
    for &word in &bits {
        first_rank.push(count);
        count += word.count_ones();
    }
    triangles.par_iter_mut().flatten().try_for_each(|v| {
        let (word, bit) = (*v as usize / 64, *v % 64);
        if bits[word] >> bit & 1 == 0 {
            return Err(Mismatch::Unlisted);
        }
        let below = bits[word] & ((1u64 << bit) - 1);
        *v = first_rank[word] + below.count_ones();
        Ok(())
    })
}

/// [`number_corners`] by searching the list for each corner: the reference.
fn by_search(triangles: &mut [[u32; 3]], listed: &[u32]) -> Result<(), Mismatch> {
    triangles.par_iter_mut().flatten().try_for_each(|v| {
        *v = listed.binary_search(v).map_err(|_| Mismatch::Unlisted)? as u32;
        Ok(())
    })
}

/// Whether every one of `count` numbered vertices is some triangle's corner.
fn every_one_used(triangles: &[[u32; 3]], count: usize) -> Result<(), Mismatch> {
    let mut used = vec![false; count];
    for &v in triangles.iter().flatten() {
        used[v as usize] = true;
    }
    if used.iter().all(|&u| u) {
        Ok(())
    } else {
        Err(Mismatch::Unused)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use proptest::prelude::*;

    /// A vertex count (either side of a word's 64 and up to 2²⁰, so that both ways are taken)
    /// and triangles over ids below it, some ids repeated.
    fn counted_triangles() -> impl Strategy<Value = (u32, Vec<[u32; 3]>)> {
        prop_oneof![1u32..300, 300u32..70_000, Just(1 << 20)].prop_flat_map(|vertex_count| {
            let id = 0..vertex_count;
            (
                Just(vertex_count),
                prop::collection::vec([id.clone(), id.clone(), id], 1..3000),
            )
        })
    }

    /// The ids `triangles` use, sorted, once each.
    fn used_ids(triangles: &[[u32; 3]]) -> Vec<u32> {
        let mut ids: Vec<u32> = triangles.iter().flatten().copied().collect();
        ids.sort_unstable();
        ids.dedup();
        ids
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        #[test]
        fn bits_and_search_number_alike((vertex_count, original) in counted_triangles()) {
            let count = original.len();
            let listed = used_ids(&original);
            let (mut bits, mut searched) = (original.clone(), original.clone());
            let words = (vertex_count as usize).div_ceil(64);
            by_bits(&mut bits, &listed, words).unwrap();
            by_search(&mut searched, &listed).unwrap();
            assert_eq!(
                &bits, &searched,
                "{count} triangles over {vertex_count} vertices"
            );
            // Each corner's number is its vertex's place in the list.
            for (corners, numbers) in original.iter().zip(&bits) {
                for (&v, &n) in corners.iter().zip(numbers) {
                    assert_eq!(listed[n as usize], v);
                }
            }
            let mut numbered = original.clone();
            assert_eq!(number_corners(&mut numbered, &listed, vertex_count), Ok(()));
            assert_eq!(numbered, searched);
        }

        #[test]
        fn a_list_short_of_a_corner_or_with_one_too_many_is_refused(
            (vertex_count, original) in counted_triangles(),
            pick in any::<prop::sample::Index>(),
        ) {
            let listed = used_ids(&original);
            let mut short = listed.clone();
            short.remove(pick.index(listed.len()));
            let words = (vertex_count as usize).div_ceil(64);
            assert_eq!(by_bits(&mut original.clone(), &short, words), Err(Mismatch::Unlisted));
            assert_eq!(by_search(&mut original.clone(), &short), Err(Mismatch::Unlisted));
            assert_eq!(
                number_corners(&mut original.clone(), &short, vertex_count),
                Err(Mismatch::Unlisted)
            );
            let unused = (0..vertex_count).find(|v| listed.binary_search(v).is_err());
            if let Some(unused) = unused {
                let mut long = listed.clone();
                long.insert(listed.partition_point(|&v| v < unused), unused);
                assert_eq!(
                    number_corners(&mut original.clone(), &long, vertex_count),
                    Err(Mismatch::Unused)
                );
            }
        }
    }

    #[test]
    fn ids_past_the_count_are_refused() {
        let mut few = vec![[0, 1, 2]];
        assert_eq!(
            number_corners(&mut few, &[0, 1], 2),
            Err(Mismatch::PastTheCount)
        );
        let mut many: Vec<[u32; 3]> = (0..1000)
            .map(|k| [k % 100, k * 7 % 100, k * 13 % 100])
            .collect();
        let listed = used_ids(&many);
        many.push([5, 100, 7]);
        assert_eq!(
            number_corners(&mut many, &listed, 100),
            Err(Mismatch::PastTheCount)
        );
        let mut edge = vec![[u32::MAX - 1, 0, 1]];
        assert_eq!(
            number_corners(&mut edge, &[0, 1, u32::MAX - 1], u32::MAX),
            Ok(())
        );
        assert_eq!(edge, vec![[2, 0, 1]]);
    }
}
