//! The allocator of `vds-build` (jemalloc) and the controls the build sets on it: when freed
//! pages go back to the kernel, and which arena a thread allocates from.

/// jemalloc, configured in `.cargo/config.toml`: a batch build allocates and frees gigabytes
/// of arrays, and keeping freed pages for reuse avoids faulting them in again.
#[global_allocator]
static ALLOCATOR: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

/// Hands the pages of freed memory back to the kernel. The allocator keeps freed memory for
/// reuse during a run (`.cargo/config.toml`: faulting fresh pages is what a build on this VM
/// waits on most), but the build leaves garbage (octree buffers, accumulators, adjacency) in
/// sizes the writer's large arrays cannot reuse, and that garbage would add to the peak: at
/// 10 M triangles, 2.48 GB instead of under 2 GB.
#[allow(unsafe_code)]
pub(crate) fn release_freed_memory() {
    // jemalloc(3): "arena.<i>.purge" with i = MALLCTL_ARENAS_ALL (4096) purges every arena.
    const PURGE_ALL: &[u8] = b"arena.4096.purge\0";
    // SAFETY: the name is a NUL-terminated string naming a control that reads and writes no
    // value, so null pointers and a zero length are the documented way to call it; purging
    // only returns unused pages to the kernel and touches no live allocation. The return
    // code is ignored: failing to purge only leaves the memory resident.
    unsafe {
        tikv_jemalloc_sys::mallctl(
            PURGE_ALL.as_ptr().cast(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            0,
        );
    }
}

/// The dirty decay of a separate sharded job ([`return_freed_memory_after`]).
pub(crate) const JOB_DECAY_MS: libc::ssize_t = 1000;

/// The dirty decay of a build within `--memory-limit` ([`return_freed_memory_after`]).
pub(crate) const LIMITED_DECAY_MS: libc::ssize_t = 200;

/// Makes the allocator hand freed memory back to the kernel from now on, instead of keeping it
/// for reuse (`.cargo/config.toml`): pages unused for about `decay_ms` milliseconds are
/// returned (jemalloc's dirty decay; 0 returns them at once). The sharded build's steps exist
/// to bound memory: each frees large buffers (a shard's input, a part once merged), and pages
/// kept past their reuse only raise the peak.
///
/// - A separate `plan`, `shard` or `merge` job after a second: each is 10-25 % faster than
///   with pages returned at once, for a peak 10-30 % higher (a shard of the 10 M scene cut
///   in four: 1.43-1.50 -> 1.23-1.26 s, 281 -> 309-312 MB; the merge of the 20 M scene
///   2.53 -> 1.93 s, 74 -> 96 MB).
/// - Within `--memory-limit` (one process, two shards at a time, then the merge) after
///   [`LIMITED_DECAY_MS`], with every thread of the build on one arena
///   ([`share_one_arena`]). Each thread allocating from an arena of its own, freed pages
///   wait for their thread: with a decay of a second the 20 M scene's shards and merge peaked
///   at 536 MB instead of 249 MB, so this build returned pages at once, and faulted them in
///   again shard after shard. On one arena a page one thread frees is the next page any
///   thread takes: the 20 M scene within 512 MiB took 16.1-17.7 s with pages returned at
///   once and 13.7-14.2 s after 200 ms on one arena (14.4-15.1 after 50 ms), peaking at
///   220-260 MB and 320-333 MB; the 10 M scene within 256 MiB 8.3 and 6.9 s, 116 and
///   182 MB.
///
/// Allocations of 8 MiB and more are not governed by this: jemalloc serves them from an arena
/// of its own for huge allocations (its `oversize_threshold`), shared by every thread, which
/// returns freed pages at once whatever the decay (jemalloc 5.3 sets that arena's decay to 0
/// when it is made after a positive default). Letting that arena keep them too
/// (`oversize_threshold:0`) measured no faster: 20 M within 512 MiB 13.4-13.8 s against
/// 13.3-15.8 s.
pub(crate) fn return_freed_memory_after(decay_ms: libc::ssize_t) {
    // The default for arenas made from now on (rayon's threads get theirs when first used),
    // and arena 0, the main thread's, which exists already. Setting a decay time only changes
    // when unused pages are purged, never a live allocation. A failure leaves the default.
    write_control(&DEFAULT_DIRTY_DECAY_MS, decay_ms);
    write_control(&ARENA_0_DIRTY_DECAY_MS, decay_ms);
}

/// Makes the calling thread allocate from jemalloc's arena 0, the one the threads of a build
/// within `--memory-limit` share ([`return_freed_memory_after`]). Arena 0 always exists.
/// Moving a thread to another arena changes only where its later allocations come from;
/// memory it allocated before is freed to the arena that holds it. A failure leaves the
/// thread where it was.
pub(crate) fn share_one_arena() {
    write_control(&THREAD_ARENA, 0);
}

/// A writable jemalloc control (jemalloc(3), "MALLCTL NAMESPACE") whose value is a `T`.
struct Control<T> {
    /// The control's name, NUL-terminated.
    name: &'static [u8],
    value: std::marker::PhantomData<T>,
}

impl<T> Control<T> {
    /// The control `name` (NUL-terminated), which must be writable and take a `T`: each
    /// constant below says where jemalloc(3) gives its type.
    const fn new(name: &'static [u8]) -> Control<T> {
        assert!(!name.is_empty() && name[name.len() - 1] == 0);
        Control {
            name,
            value: std::marker::PhantomData,
        }
    }
}

/// `arenas.dirty_decay_ms (ssize_t) rw`: the dirty decay of arenas made from now on.
const DEFAULT_DIRTY_DECAY_MS: Control<libc::ssize_t> = Control::new(b"arenas.dirty_decay_ms\0");
/// `arena.<i>.dirty_decay_ms (ssize_t) rw`, for arena 0.
const ARENA_0_DIRTY_DECAY_MS: Control<libc::ssize_t> = Control::new(b"arena.0.dirty_decay_ms\0");
/// `thread.arena (unsigned) rw`: the calling thread's arena.
const THREAD_ARENA: Control<libc::c_uint> = Control::new(b"thread.arena\0");

/// Writes `value` to `control`; a failure (jemalloc's return code) is ignored.
#[allow(unsafe_code)]
fn write_control<T>(control: &Control<T>, value: T) {
    // SAFETY: `control.name` is NUL-terminated (checked when the constant was made) and names
    // a writable control whose value is a `T` (each constant's documented type); the new
    // value points to a live `T` of the size passed, and no old value is asked for (null
    // pointers), as jemalloc(3) documents for writing a control.
    unsafe {
        tikv_jemalloc_sys::mallctl(
            control.name.as_ptr().cast(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            (&value as *const T).cast_mut().cast(),
            size_of::<T>(),
        );
    }
}
