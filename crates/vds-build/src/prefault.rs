//! Faulting in fresh memory ahead of the code that will fill it.
//!
//! The first write to each 4 KiB page of a new allocation traps into the kernel, which then
//! zeroes the page. On the 2-core dev VMs that costs 0.55 s per GB when the pages are touched
//! one at a time, against 0.31 s per GB when `madvise(MADV_POPULATE_WRITE)` maps a whole range
//! in one call (measured with a C program touching 1 GB either way; docs/benchmarks.md), and
//! the build faults in about 1.8 GB for 10 M triangles. Where a loop that must stay sequential
//! appends to a large array (the clustering's node array, one level at a time), the range it
//! is about to write is populated first, in parallel pieces, so that neither the traps nor the
//! zeroing are left to the one thread.
//!
//! Only a hint: where the call is unknown (kernels before 5.14, other systems) nothing
//! happens and the pages fault in as they are written, as before.

use std::mem::MaybeUninit;

use rayon::prelude::*;

/// Bytes per parallel `madvise` call.
const PIECE_BYTES: usize = 4 << 20;

/// Below this many bytes, populating is left to the page faults: a call and a thread hand-off
/// cost more than they save.
const MIN_BYTES: usize = 1 << 20;

/// Maps every whole page of `spare` (memory the caller is about to write) writable and zeroed,
/// in parallel pieces. Contents are unchanged: pages already mapped are left as they are, and
/// `spare` is uninitialised memory anyway.
pub(crate) fn populate<T>(spare: &mut [MaybeUninit<T>]) {
    let bytes = std::mem::size_of_val(spare);
    if bytes < MIN_BYTES {
        return;
    }
    let start = spare.as_mut_ptr() as usize;
    let page = 4096;
    let first = start.next_multiple_of(page);
    let end = (start + bytes) / page * page;
    if end <= first {
        return;
    }
    let pieces = (end - first).div_ceil(PIECE_BYTES);
    (0..pieces).into_par_iter().for_each(|k| {
        let piece = first + k * PIECE_BYTES;
        populate_range(piece, (end - piece).min(PIECE_BYTES));
    });
}

/// `items` collected into a vector whose pages are populated first: the parallel writes then
/// find them mapped instead of faulting them in one at a time.
pub(crate) fn collect_populated<T: Send>(items: impl IndexedParallelIterator<Item = T>) -> Vec<T> {
    let mut v = Vec::with_capacity(items.len());
    populate(v.spare_capacity_mut());
    v.par_extend(items);
    v
}

/// `vec![value; n]` for the build's large index arrays, which single-threaded loops then fill
/// in random order: the pages are populated and the values written in parallel first, instead
/// of the pages faulting in one at a time under the loop.
pub(crate) fn filled<T: Copy + Send + Sync>(n: usize, value: T) -> Vec<T> {
    collect_populated(rayon::iter::repeat_n(value, n))
}

#[cfg(target_os = "linux")]
fn populate_range(address: usize, length: usize) {
    #[allow(unsafe_code)]
    // SAFETY: `address .. address + length` lies inside the slice `populate` borrows mutably
    // (page-aligned, rounded inwards), so no other code reads or writes it meanwhile.
    // MADV_POPULATE_WRITE only populates page tables as write faults would (private
    // anonymous pages that were never written become zeroed pages; present pages stay as
    // they are); it changes no byte of memory a program can read, and no mapping. An error
    // (EINVAL on kernels before 5.14, ENOMEM) is ignored: the pages then fault in on first
    // write, as without the call.
    unsafe {
        libc::madvise(
            address as *mut libc::c_void,
            length,
            libc::MADV_POPULATE_WRITE,
        );
    }
}

#[cfg(not(target_os = "linux"))]
fn populate_range(_address: usize, _length: usize) {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn populating_changes_no_contents() {
        let mut v: Vec<u64> = (0..1_000_000).collect();
        v.reserve(3_000_000);
        populate(v.spare_capacity_mut());
        assert!(v.iter().enumerate().all(|(i, &x)| x == i as u64));
        v.extend(0..3_000_000u64);
        assert_eq!(v[1_000_000 + 2_999_999], 2_999_999);
    }

    #[test]
    fn filled_is_vec_of_copies() {
        assert_eq!(filled(3_000_001, 7u32), vec![7u32; 3_000_001]);
        assert!(filled(0, 1u8).is_empty());
    }
}
