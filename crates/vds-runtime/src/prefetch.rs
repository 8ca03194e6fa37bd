//! Cache prefetch hints: asking the CPU to start loading memory the traversal will read a few
//! steps later, so that the misses of those reads overlap with the work in between instead of
//! stalling it one after another.
//!
//! A hint never changes what a program computes: it reads nothing, cannot fault on any
//! address, and on targets without an instruction for it does nothing.

/// Hints that the elements of `slice` in `range` will be read soon. Ranges past the end of
/// the slice are clamped; an empty range hints nothing.
#[inline]
pub(crate) fn prefetch_range<T>(slice: &[T], range: std::ops::Range<usize>) {
    let Some(items) = slice.get(range.start..range.end.min(slice.len())) else {
        return;
    };
    let start = items.as_ptr().cast::<u8>();
    let bytes = std::mem::size_of_val(items) as isize;
    // One hint per 64-byte line the elements touch, starting at the line of the first byte.
    let mut offset = -((start as usize % LINE) as isize);
    while offset < bytes {
        prefetch_line(start.wrapping_offset(offset));
        offset += LINE as isize;
    }
}

/// The cache line size the hints step by (x86-64 and most ARM cores).
const LINE: usize = 64;

#[inline]
fn prefetch_line(address: *const u8) {
    #[cfg(target_arch = "x86_64")]
    #[allow(unsafe_code)]
    // SAFETY: `_mm_prefetch` is unsafe only because it needs the `sse` target feature, which
    // every x86-64 CPU has (it is in the x86_64 targets' baseline). PREFETCHT0 does not access
    // memory architecturally: it cannot fault, whatever the address, and changes no state a
    // program can observe except timing.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(address.cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = address;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hints_accept_any_range() {
        let data = vec![0u64; 100];
        prefetch_range(&data, 0..100);
        prefetch_range(&data, 90..200);
        prefetch_range(&data, 150..200);
        prefetch_range(&data, 5..5);
        prefetch_range::<u64>(&[], 0..8);
        assert_eq!(data.iter().sum::<u64>(), 0);
    }
}
