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
//!
//! ## Looking ahead
//! A cut descends a page level per frame if pages are asked for only by the nodes waiting
//! for them: the adjust unfolds into a page the frame after it arrives, and only then finds
//! the next page down. So the store hands the workers the last adjust's view and threshold
//! ([`Foresight`]), and a worker that has decoded a page tests its nodes as the adjust will:
//! a node the cut would reach (its parent is in another page, or unfolds in this one) that
//! would unfold has its children's pages asked for at once, with its screen error as the
//! priority. The descent then runs at decoding speed, several page levels within a frame.
//! It is held to the room the store's budget has for pages nobody awaits, so it never
//! decodes what the store could not take in.

use std::collections::BinaryHeap;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;

use vds_format::{Page, VdtError};

use crate::criteria::{Decision, Judge};
use crate::store::{Node, PageSource, Tested, page_holding, tested_parts};

/// Decoded pages that may wait per worker for the store to take them in, at least.
pub(crate) const WAITING: usize = 32;

/// The loader's bytes per page of the file (`taken`, `in_flight`, `foreseen`), counted in
/// the store's table bytes.
pub(crate) const PER_PAGE_BYTES: usize = 3 * size_of::<bool>();

/// What the workers look ahead with ([module documentation](self)): the view and threshold
/// of the last adjust, and how many more pages the store has room for.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Foresight {
    pub(crate) judge: Judge,
    pub(crate) t: f32,
    /// Pages the store could take in now besides those it awaits.
    pub(crate) room: u32,
}

/// A decoded page, or why it could not be read.
pub(crate) type Loaded = (u32, Result<Page, VdtError>);

/// The worker threads and the two ends of their queue.
pub(crate) struct Loader {
    shared: Arc<Shared>,
    /// `None` only while dropping: closing it first unblocks a worker waiting to send. In a
    /// mutex only so that the store can be read from several threads (the threshold pass's
    /// tests, which never touch the loader): its owner alone locks it, uncontended.
    results: Option<Mutex<Receiver<Loaded>>>,
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
    /// Per page: a worker has taken it and the store has not yet received it, so asking for
    /// it again asks for nothing: it is on its way.
    in_flight: Vec<bool>,
    /// Per page: asked for by a worker looking ahead, and not yet received by the store.
    foreseen: Vec<bool>,
    /// How many pages are `foreseen`.
    foreseen_count: u32,
    /// How many pages are `in_flight`.
    in_flight_count: u32,
    foresight: Option<Foresight>,
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
    /// Starts `threads` workers (at least one) reading pages of `source`, whose pages start
    /// at the nodes `first_nodes` (the store's, for looking ahead), with at most
    /// `waiting` decoded pages (at least [`WAITING`] per worker) waiting for the store; fails
    /// when the system cannot start a thread.
    pub(crate) fn start(
        source: Arc<dyn PageSource>,
        first_nodes: Arc<[u32]>,
        threads: usize,
        waiting: usize,
    ) -> Result<Loader, VdtError> {
        let page_count = source.directory().len();
        let shared = Arc::new(Shared {
            queue: Mutex::new(Queue {
                requests: BinaryHeap::new(),
                taken: vec![false; page_count],
                in_flight: vec![false; page_count],
                foreseen: vec![false; page_count],
                foreseen_count: 0,
                in_flight_count: 0,
                foresight: None,
                stop: false,
            }),
            wake: Condvar::new(),
        });
        // Decoded pages wait here until the store takes them in, a bounded number: a store
        // that does not poll (a viewer waiting for input) stops the workers instead of
        // letting decoded pages pile up outside its memory budget, and one that polls once a
        // frame still takes in a frame's worth of pages from each worker.
        let threads = threads.max(1);
        let (sender, results) = sync_channel(waiting.max(WAITING * threads));
        let mut loader = Loader {
            shared,
            results: Some(Mutex::new(results)),
            workers: Vec::new(),
        };
        for k in 0..threads {
            let (shared, source, sender, first_nodes) = (
                Arc::clone(&loader.shared),
                Arc::clone(&source),
                sender.clone(),
                Arc::clone(&first_nodes),
            );
            let worker = std::thread::Builder::new()
                .name(format!("vds-pages-{k}"))
                .spawn(move || work(&shared, source.as_ref(), &first_nodes, &sender))
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
        if queue.in_flight[page as usize] {
            return; // The store receives it soon.
        }
        if fresh {
            queue.taken[page as usize] = false;
        }
        if !queue.taken[page as usize] {
            queue.requests.push(Request { priority, page });
            drop(queue);
            self.shared.wake.notify_one();
        }
    }

    /// Hands the workers the view to look ahead with, or `None` to stop looking ahead.
    pub(crate) fn foresee(&self, foresight: Option<Foresight>) {
        self.lock().foresight = foresight;
    }

    /// Tells the workers that the store has received `pages` (taken in, dropped or failed):
    /// asking for one of them again loads it again.
    pub(crate) fn received(&self, pages: &[u32]) {
        if pages.is_empty() {
            return;
        }
        let mut queue = self.lock();
        for &page in pages {
            if std::mem::replace(&mut queue.in_flight[page as usize], false) {
                queue.in_flight_count -= 1;
            }
            if std::mem::replace(&mut queue.foreseen[page as usize], false) {
                queue.foreseen_count -= 1;
            }
        }
    }

    /// Whether a worker has a page to decode or one the store has not received: a request
    /// not yet taken (the store's or one looking ahead), or a page taken and not received.
    pub(crate) fn busy(&self) -> bool {
        let queue = self.lock();
        queue.in_flight_count > 0
            || queue
                .requests
                .iter()
                .any(|request| !queue.taken[request.page as usize])
    }

    /// Takes back the requests for `pages` that no worker has taken yet: they are skipped
    /// until asked for afresh. Pages a worker is decoding or has decoded still arrive.
    pub(crate) fn cancel(&self, pages: &[u32]) {
        if pages.is_empty() {
            return;
        }
        let mut queue = self.lock();
        for &page in pages {
            let p = page as usize;
            if !queue.in_flight[p] && !queue.foreseen[p] {
                queue.taken[p] = true;
            }
        }
    }

    /// A page a worker has finished since the last call, if any; never blocks.
    pub(crate) fn try_next(&self) -> Option<Loaded> {
        self.receiver()?.try_recv().ok()
    }

    /// The next page a worker finishes, waiting for it (for callers that want loading to
    /// settle: tests, batch replays). `None` if every worker has stopped.
    pub(crate) fn wait_next(&self) -> Option<Loaded> {
        self.receiver()?.recv().ok()
    }

    fn receiver(&self) -> Option<std::sync::MutexGuard<'_, Receiver<Loaded>>> {
        // Receiving never panics while the lock is held, so a poisoned lock is still sound.
        let results = self.results.as_ref()?;
        Some(
            results
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner),
        )
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

/// A worker: takes the most urgent request not yet taken, decodes it, asks for the pages
/// below it that the cut will reach ([`foresee`]), sends it back.
fn work(
    shared: &Shared,
    source: &dyn PageSource,
    first_nodes: &[u32],
    results: &SyncSender<Loaded>,
) {
    let mut below = Vec::new();
    let mut unfolds = Vec::new();
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
                        let p = request.page as usize;
                        queue.taken[p] = true;
                        queue.in_flight[p] = true;
                        queue.in_flight_count += 1;
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
        // The view of the latest adjust, which may be newer than the request.
        let foresight = shared
            .queue
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .foresight;
        if let (Ok(decoded), Some(foresight)) = (&result, foresight)
            && foresight.room > 0
        {
            below.clear();
            foresee(&foresight, decoded, first_nodes, &mut unfolds, &mut below);
            if !below.is_empty() {
                ask_ahead(shared, &below);
            }
        }
        if results.send((page, result)).is_err() {
            return; // The store is gone.
        }
    }
}

/// The pages below `page` that an adjust under `foresight` will need next, with their
/// priorities, into `below`: the children's pages of each node of `page` that the cut would
/// reach and that would unfold. A node is taken to be reached when its parent is in another
/// page (the page was asked for because the cut came near it) or unfolds in this one.
fn foresee(
    foresight: &Foresight,
    page: &Page,
    first_nodes: &[u32],
    unfolds: &mut Vec<bool>,
    below: &mut Vec<Request>,
) {
    let count = page.nodes.len();
    let ids = page.first_node..page.first_node.saturating_add(count as u32);
    unfolds.clear();
    unfolds.resize(count, false);
    for (i, record) in page.nodes.iter().enumerate() {
        let node = Node::from_record(record);
        if node.child_count == 0 {
            continue;
        }
        // A parent in this page comes before its children (ids grow downwards); one that
        // does not is taken as not unfolding, which only asks for less.
        let reached = match node.parent.checked_sub(page.first_node) {
            Some(local) if ids.contains(&node.parent) => {
                (local as usize) < i && unfolds[local as usize]
            }
            _ => true,
        };
        if !reached {
            continue;
        }
        let (hot, shape) = tested_parts(&node);
        let tested = Tested {
            hot: &hot,
            shape: &shape,
        };
        if foresight.judge.decide(tested, foresight.t) != Decision::Unfold {
            continue;
        }
        unfolds[i] = true;
        let last = node
            .first_child
            .saturating_add(u32::from(node.child_count) - 1);
        if ids.contains(&node.first_child) && ids.contains(&last) {
            continue;
        }
        let priority = foresight.judge.screen_error(tested);
        let pages = page_holding(first_nodes, node.first_child)..=page_holding(first_nodes, last);
        for child_page in pages {
            below.push(Request {
                priority,
                page: child_page as u32,
            });
        }
    }
}

/// Queues the pages of `below` that are neither loaded nor on their way, within the store's
/// room ([`Foresight::room`]), and wakes the workers.
fn ask_ahead(shared: &Shared, below: &[Request]) {
    let mut queue = shared.queue.lock().unwrap_or_else(PoisonError::into_inner);
    let room = queue.foresight.map_or(0, |f| f.room);
    let mut asked = 0;
    for request in below {
        if queue.foreseen_count >= room {
            break;
        }
        let p = request.page as usize;
        if queue.taken[p] || queue.in_flight[p] || queue.foreseen[p] {
            continue;
        }
        queue.foreseen[p] = true;
        queue.foreseen_count += 1;
        queue.requests.push(*request);
        asked += 1;
    }
    drop(queue);
    if asked > 1 {
        shared.wake.notify_all();
    } else if asked == 1 {
        shared.wake.notify_one();
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
