//! `vds-bench first-touch`: how fast this machine hands a process fresh memory. The first
//! write to each page of a new allocation traps into the kernel (and, in a VM, possibly into
//! the host, which may have taken free guest memory back: the dev VMs run with free page
//! reporting), so a build's wall time depends on how much memory it touches for the first
//! time and on this rate, which on the dev VMs moved between 0.4 and 2.6 GB/s with what had
//! run before. Print it beside build timings that are to be compared.

use std::time::Instant;

/// Allocates `megabytes` of zeroed memory (fresh pages, none touched yet), writes one byte
/// per 4 KiB page, then fills the whole range, and prints both rates.
pub fn run(megabytes: usize) {
    let bytes = megabytes << 20;
    // Zeroed allocations this large come straight from fresh mappings: nothing is written.
    let mut memory = vec![0u8; bytes];
    let start = Instant::now();
    for i in (0..bytes).step_by(4096) {
        memory[i] = 1;
    }
    let first = start.elapsed().as_secs_f64();
    std::hint::black_box(&memory);
    let start = Instant::now();
    memory.fill(2);
    let again = start.elapsed().as_secs_f64();
    std::hint::black_box(&memory);
    println!(
        "{megabytes} MiB: first touch {first:.3} s = {:.2} GB/s; filling it again {again:.3} s = {:.2} GB/s",
        bytes as f64 / first / 1e9,
        bytes as f64 / again / 1e9
    );
}
