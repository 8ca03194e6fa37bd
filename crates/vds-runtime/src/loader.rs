//! Background page loading: worker threads that read, check and decode pages off the thread
//! that adjusts the cut, most urgent first (Luebke & Erikson §4.4's asynchronous
//! simplification, applied to paging).
//!
//! The store asks for a page with a priority (how far past its threshold the node waiting
//! for it is, in pixels); workers take the most urgent request, decode the page through the
//! [`PageSource`] and hand the result back through a channel that the store drains, without
//! blocking, at the start of the next adjust. A page asked for again with a higher priority
//! is queued again; whichever entry a worker reaches first loads it, and the others are
//! skipped. Dropping the loader stops the workers after the page each is decoding.

use std::collections::BinaryHeap;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;

use vds_format::{Page, VdtError};

use crate::store::PageSource;

/// Decoded pages that may wait per worker for the store to take them in.
pub(crate) const WAITING: usize = 32;

/// A decoded page, or why it could not be read.
pub(crate) type Loaded = (u32, Result<Page, VdtError>);

/// The worker threads and the two ends of their queue.
pub(crate) struct Loader {
    shared: Arc<Shared>,
    /// `None` only while dropping: closing it first unblocks a worker waiting to send.
    results: Option<Receiver<Loaded>>,
    workers: Vec<JoinHandle<()>>,
}

struct Shared {
    queue: Mutex<Queue>,
    wake: Condvar,
}

struct Queue {
    requests: BinaryHeap<Request>,
    /// Per page: a worker has taken it (loaded or failed) since it was last asked for
    /// afresh, so later entries are skipped.
    taken: Vec<bool>,
    stop: bool,
}

/// One queued request: more urgent first, then lower page index (deterministic order).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Request {
    priority: f32,
    page: u32,
}

impl Eq for Request {}

impl PartialOrd for Request {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Request {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.priority
            .total_cmp(&other.priority)
            .then(other.page.cmp(&self.page))
    }
}

impl Loader {
    /// Starts `threads` workers (at least one) reading pages of `source`; fails when the
    /// system cannot start a thread.
    pub(crate) fn start(source: Arc<dyn PageSource>, threads: usize) -> Result<Loader, VdtError> {
        let page_count = source.directory().len();
        let shared = Arc::new(Shared {
            queue: Mutex::new(Queue {
                requests: BinaryHeap::new(),
                taken: vec![false; page_count],
                stop: false,
            }),
            wake: Condvar::new(),
        });
        // Decoded pages wait here until the store takes them in, at most WAITING per
        // worker: a store that does not poll (a viewer waiting for input) stops the workers
        // instead of letting decoded pages pile up outside its memory budget, and one that
        // polls once a frame still takes in a frame's worth of pages from each worker.
        let threads = threads.max(1);
        let (sender, results) = sync_channel(WAITING * threads);
        let mut loader = Loader {
            shared,
            results: Some(results),
            workers: Vec::new(),
        };
        for k in 0..threads {
            let (shared, source, sender) = (
                Arc::clone(&loader.shared),
                Arc::clone(&source),
                sender.clone(),
            );
            let worker = std::thread::Builder::new()
                .name(format!("vds-pages-{k}"))
                .spawn(move || work(&shared, source.as_ref(), &sender))
                .map_err(|e| {
                    VdtError::invalid("page loader", format!("cannot start a thread: {e}"))
                })?;
            loader.workers.push(worker);
        }
        Ok(loader)
    }

    /// Asks for page `page` with `priority` (higher first). `fresh` when the store is not
    /// awaiting the page already (it was never asked for, or it was delivered and has since
    /// been evicted or refused): the page is loaded again even if a worker loaded it before.
    pub(crate) fn request(&self, page: u32, priority: f32, fresh: bool) {
        let mut queue = self.lock();
        if fresh {
            queue.taken[page as usize] = false;
        }
        if !queue.taken[page as usize] {
            queue.requests.push(Request { priority, page });
            drop(queue);
            self.shared.wake.notify_one();
        }
    }

    /// A page a worker has finished since the last call, if any; never blocks.
    pub(crate) fn try_next(&self) -> Option<Loaded> {
        self.results.as_ref()?.try_recv().ok()
    }

    /// The next page a worker finishes, waiting for it (for callers that want loading to
    /// settle: tests, batch replays). `None` if every worker has stopped.
    pub(crate) fn wait_next(&self) -> Option<Loaded> {
        self.results.as_ref()?.recv().ok()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Queue> {
        // A worker never panics while holding the lock (it only pushes and pops), so a
        // poisoned lock still guards consistent data.
        self.shared
            .queue
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
    }
}

impl Drop for Loader {
    fn drop(&mut self) {
        self.lock().stop = true;
        self.shared.wake.notify_all();
        self.results = None;
        for worker in self.workers.drain(..) {
            let _ = worker.join();
        }
    }
}

/// A worker: takes the most urgent request not yet taken, decodes it, sends it back.
fn work(shared: &Shared, source: &dyn PageSource, results: &SyncSender<Loaded>) {
    loop {
        let page = {
            let mut queue = shared.queue.lock().unwrap_or_else(PoisonError::into_inner);
            loop {
                if queue.stop {
                    return;
                }
                match queue.requests.pop() {
                    Some(request) if queue.taken[request.page as usize] => continue,
                    Some(request) => {
                        queue.taken[request.page as usize] = true;
                        break request.page;
                    }
                    None => {
                        queue = shared
                            .wake
                            .wait(queue)
                            .unwrap_or_else(PoisonError::into_inner);
                    }
                }
            }
        };
        let mut decoded = Page {
            first_node: 0,
            first_triangle: 0,
            nodes: Vec::new(),
            triangles: Vec::new(),
        };
        // A page source that panics must not leave the page awaited forever (the store would
        // wait for it): the panic becomes that page's error.
        let read = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            source.read_page_into(page, &mut decoded)
        }));
        let result = match read {
            Ok(result) => result.map(|()| decoded),
            Err(_) => Err(VdtError::invalid(
                format!("page {page}"),
                "the page source panicked while reading it",
            )),
        };
        if results.send((page, result)).is_err() {
            return; // The store is gone.
        }
    }
}

/// The default number of loading threads: the cores but one (the adjusting thread's),
/// at least one and at most four (decoding runs at hundreds of MB/s a core; more threads
/// would only compete with the renderer).
pub fn default_threads() -> usize {
    std::thread::available_parallelism()
        .map_or(1, |n| n.get().saturating_sub(1))
        .clamp(1, 4)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_come_out_most_urgent_first_then_lowest_page() {
        let mut heap = BinaryHeap::new();
        for (priority, page) in [(1.0, 5), (3.0, 2), (3.0, 1), (0.5, 0)] {
            heap.push(Request { priority, page });
        }
        let order: Vec<u32> = std::iter::from_fn(|| heap.pop().map(|r| r.page)).collect();
        assert_eq!(order, [1, 2, 5, 0]);
    }
}
