//! `vds-bench latency`: how long one dependent memory read takes at several working-set
//! sizes, to tell how a machine's caches and memory compare with another's before comparing
//! the runtime's or the builder's figures across machines (both are bound by cache misses).
//!
//! The reads follow one random cycle through an array (Sattolo's shuffle makes a single
//! cycle), so each address depends on the previous read and no prefetcher can guess it.

use std::time::Instant;

/// Prints the time per dependent read for working sets from 32 KiB to 256 MiB.
pub fn run() {
    println!("dependent random reads (one cycle through the working set):");
    for shift in [15, 18, 20, 22, 24, 26, 28] {
        let bytes = 1usize << shift;
        let ns = nanoseconds_per_read(bytes / size_of::<usize>(), 0x9E37_79B9_7F4A_7C15);
        println!("  {:>9} KiB  {ns:7.1} ns", bytes >> 10);
    }
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
