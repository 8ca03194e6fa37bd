//! `vds-bench latency`: how long one dependent memory read takes at several working-set
//! sizes, to tell how a machine's caches and memory compare with another's before comparing
//! the runtime's or the builder's figures across machines (both are bound by cache misses).
//!
//! The reads follow one random cycle through an array (Sattolo's shuffle makes a single
//! cycle), so each address depends on the previous read and no prefetcher can guess it.
//!
//! Then what one core streams: a sum over an array larger than the caches, read forwards and
//! backwards (the runtime reads its active list backwards), for the floor of any per-frame
//! pass over data that does not stay in cache.

use std::time::Instant;

/// Prints the time per dependent read for working sets from 32 KiB to 256 MiB.
pub fn run() {
    println!("dependent random reads (one cycle through the working set):");
    for shift in [15, 18, 20, 22, 24, 26, 28] {
        let bytes = 1usize << shift;
        let ns = nanoseconds_per_read(bytes / size_of::<usize>(), 0x9E37_79B9_7F4A_7C15);
        println!("  {:>9} KiB  {ns:7.1} ns", bytes >> 10);
    }
    println!("streaming reads, one core, 256 MiB (median of 5 passes):");
    let words = vec![1u64; (256 << 20) / size_of::<u64>()];
    for (direction, backwards) in [("forwards", false), ("backwards", true)] {
        let mut seconds: Vec<f64> = (0..5).map(|_| seconds_to_sum(&words, backwards)).collect();
        seconds.sort_by(f64::total_cmp);
        let gb_per_s = (words.len() * size_of::<u64>()) as f64 / seconds[2] / 1e9;
        println!("  {direction:<9} {gb_per_s:6.2} GB/s");
    }
}

/// Seconds to sum `words` in one pass, in either direction. Four independent sums, so the
/// additions keep up with memory.
fn seconds_to_sum(words: &[u64], backwards: bool) -> f64 {
    let start = Instant::now();
    let mut sums = [0u64; 4];
    let mut add = |chunk: &[u64]| {
        for (sum, &word) in sums.iter_mut().zip(chunk) {
            *sum = sum.wrapping_add(word);
        }
    };
    if backwards {
        words.chunks_exact(4).rev().for_each(&mut add);
    } else {
        words.chunks_exact(4).for_each(&mut add);
    }
    let elapsed = start.elapsed().as_secs_f64();
    std::hint::black_box(sums);
    elapsed
}

fn nanoseconds_per_read(len: usize, mut seed: u64) -> f64 {
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    // Sattolo's algorithm: a uniformly random permutation with a single cycle.
    let mut links: Vec<usize> = (0..len).collect();
    for i in (1..len).rev() {
        let j = (next() % i as u64) as usize;
        links.swap(i, j);
    }
    let reads = 20_000_000usize;
    let mut at = 0usize;
    let start = Instant::now();
    for _ in 0..reads {
        at = links[at];
    }
    let elapsed = start.elapsed().as_secs_f64();
    std::hint::black_box(at);
    elapsed * 1e9 / reads as f64
}
