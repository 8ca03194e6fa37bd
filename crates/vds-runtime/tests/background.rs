//! Background page loading: no adjust reads a page itself; a node whose children are not
//! resident stays folded and unfolds after they arrive; once loading settles the cut meets
//! the same screen-space bound as with synchronous loading; a page the loader cannot read is
//! reported once and its nodes stay folded while the runtime goes on.

mod common;

use std::sync::{Arc, Mutex};
use std::thread::ThreadId;

use common::*;
use vds_format::{Header, Page, PageEntry, VdtError, VdtFile};
use vds_runtime::{
    CornerTracking, Criteria, Goal, Loading, NodeState, PageSource, Runtime, Viewpoint, measure,
};

/// A page source that records which thread read each page (shared with the test).
struct Recording {
    file: VdtFile<Vec<u8>>,
    reads: Arc<Mutex<Vec<(u32, ThreadId)>>>,
}

impl PageSource for Recording {
    fn header(&self) -> &Header {
        self.file.header()
    }
    fn directory(&self) -> &[PageEntry] {
        self.file.directory()
    }
    fn read_page_into(&self, index: u32, page: &mut Page) -> Result<(), VdtError> {
        self.reads
            .lock()
            .unwrap()
            .push((index, std::thread::current().id()));
        self.file.read_page_into(index, page)
    }
}

/// Opens the gate when dropped, so a failing assertion unwinds past the runtime's drop
/// (which joins a worker waiting at the gate) instead of hanging the test.
struct OpenOnDrop(Arc<(Mutex<bool>, std::sync::Condvar)>);

impl Drop for OpenOnDrop {
    fn drop(&mut self) {
        let (open, opened) = &*self.0;
        *open.lock().unwrap_or_else(|poisoned| poisoned.into_inner()) = true;
        opened.notify_all();
    }
}

fn background(bytes: &[u8], threads: usize) -> Runtime {
    Runtime::with_loading(
        Box::new(VdtFile::from_bytes(bytes.to_vec()).unwrap()),
        CornerTracking::Incidence,
        Loading::Background { threads },
    )
    .unwrap()
}

/// Adjusts for `camera` until no unfold waits for a page, letting loading settle between
/// adjusts; returns how many adjusts that took.
fn settle(runtime: &mut Runtime, viewpoint: &Viewpoint, criteria: &Criteria, goal: Goal) -> u32 {
    for round in 1..=200 {
        let frame = runtime.adjust(viewpoint, criteria, goal).unwrap();
        if frame.stats.deferred_unfolds == 0 && runtime.pending_pages() == 0 {
            // Pages fetched ahead of need, or asked for by the loader looking ahead, may
            // still be on their way: taken in now, so that what a test does next starts
            // from an idle loader whatever the threads' timing.
            runtime.wait_for_pages();
            return round;
        }
        runtime.wait_for_pages();
    }
    panic!("loading never settled");
}

fn no_backface() -> Criteria {
    Criteria {
        backface: false,
        ..Criteria::default()
    }
}

#[test]
fn settled_background_cuts_meet_the_threshold_and_match_synchronous_ones() {
    for name in ["bunny.obj", "as1_assembly.obj"] {
        let mut scene = load(name);
        let bytes = vdt_bytes(&mut scene);
        let (center, radius) = bounds(&scene.positions);
        let mut synchronous = runtime(&bytes, CornerTracking::Incidence);
        let positions = synchronous.leaf_positions().unwrap();
        let mut synchronous = runtime(&bytes, CornerTracking::Incidence);
        let mut asynchronous = background(&bytes, 2);
        let mut rng = Rng(7);
        let mut deferred_somewhere = false;
        for step in 0..12 {
            let camera = random_camera(&mut rng, center, radius);
            let viewpoint = Viewpoint::Camera(camera);
            let t = [0.5f32, 1.0, 3.0][step % 3];
            let goal = Goal::Threshold(t);
            synchronous
                .adjust(&viewpoint, &no_backface(), goal)
                .unwrap();
            let rounds = settle(&mut asynchronous, &viewpoint, &no_backface(), goal);
            deferred_somewhere |= rounds > 1;
            asynchronous.cut_mut().check().unwrap();
            let deviation =
                measure::screen_deviation(asynchronous.cut(), &camera.view(), &positions, None);
            assert!(
                deviation.max_px <= f64::from(t) * (1.0 + 1e-4) + 1e-4,
                "{name} step {step}: {} px > {t} px once loading settled",
                deviation.max_px
            );
            assert_eq!(
                asynchronous.cut().boundary(),
                synchronous.cut().boundary(),
                "{name} step {step}: the settled cut differs from the synchronous one"
            );
        }
        assert!(
            deferred_somewhere,
            "{name}: no unfold ever waited for a page"
        );
    }
}

#[test]
fn budget_mode_settles_within_the_budget() {
    let mut scene = load("bunny.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let mut runtime = background(&bytes, 1);
    let mut rng = Rng(3);
    let mut deferred = 0;
    for budget in [500u32, 2_000, 8_000] {
        let viewpoint = Viewpoint::Camera(random_camera(&mut rng, center, radius));
        let goal = Goal::Budget(budget);
        let mut frames = 0;
        loop {
            let frame = runtime.adjust(&viewpoint, &no_backface(), goal).unwrap();
            assert!(runtime.cut().active_triangle_count() <= budget);
            deferred += frame.stats.deferred_unfolds;
            frames += 1;
            if frame.stats.deferred_unfolds == 0 && runtime.pending_pages() == 0 {
                break;
            }
            assert!(frames < 200, "loading never settled");
            runtime.wait_for_pages();
        }
        // Settled: what is left to unfold would not fit.
        assert!(runtime.cut().active_triangle_count() > budget / 2);
    }
    assert!(deferred > 0, "no budget unfold ever waited for a page");
}

/// A page source that panics on one page.
struct Panicking {
    file: VdtFile<Vec<u8>>,
    page: u32,
}

impl PageSource for Panicking {
    fn header(&self) -> &Header {
        self.file.header()
    }
    fn directory(&self) -> &[PageEntry] {
        self.file.directory()
    }
    fn read_page_into(&self, index: u32, page: &mut Page) -> Result<(), VdtError> {
        assert_ne!(index, self.page, "a page source with a bug");
        self.file.read_page_into(index, page)
    }
}

#[test]
fn a_page_source_that_panics_becomes_that_pages_error_not_a_hang() {
    let mut scene = load("bunny.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let source = Panicking {
        file: VdtFile::from_bytes(bytes).unwrap(),
        page: 1,
    };
    let mut runtime = Runtime::with_loading(
        Box::new(source),
        CornerTracking::Incidence,
        Loading::Background { threads: 1 },
    )
    .unwrap();
    let mut errors = Vec::new();
    let mut rng = Rng(9);
    for _ in 0..10 {
        let viewpoint = Viewpoint::Camera(random_camera(&mut rng, center, radius * 0.5));
        for _ in 0..3 {
            runtime
                .adjust(&viewpoint, &no_backface(), Goal::Threshold(0.5))
                .unwrap();
            // Returns: the panicking page is delivered as an error, not left awaited.
            runtime.wait_for_pages();
            errors.extend(runtime.take_page_errors());
        }
    }
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(errors[0].to_string().contains("panicked"), "{}", errors[0]);
}

#[test]
fn no_adjust_reads_a_page_on_its_own_thread() {
    let mut scene = load("bunny.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let reads = Arc::new(Mutex::new(Vec::new()));
    let source = Recording {
        file: VdtFile::from_bytes(bytes).unwrap(),
        reads: Arc::clone(&reads),
    };
    let mut runtime = Runtime::with_loading(
        Box::new(source),
        CornerTracking::Incidence,
        Loading::Background { threads: 2 },
    )
    .unwrap();
    let me = std::thread::current().id();
    let count = || {
        let reads = reads.lock().unwrap();
        let here = reads.iter().filter(|(_, thread)| *thread == me).count();
        (here, reads.len() - here)
    };
    assert_eq!(
        count(),
        (1, 0),
        "the root's page is read when the runtime opens"
    );
    let mut rng = Rng(11);
    for _ in 0..8 {
        let viewpoint = Viewpoint::Camera(random_camera(&mut rng, center, radius));
        for _ in 0..4 {
            runtime
                .adjust(&viewpoint, &Criteria::default(), Goal::Threshold(1.0))
                .unwrap();
            runtime.wait_for_pages();
        }
    }
    let (here, elsewhere) = count();
    assert_eq!(here, 1, "an adjust read a page itself");
    assert!(elsewhere > 10, "the loader read only {elsewhere} pages");
}

#[test]
fn a_page_the_loader_cannot_read_is_reported_once_and_its_nodes_stay_folded() {
    let mut scene = load("bunny.obj");
    let mut bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    // Corrupt the page holding the root's first child (not the root's own page, which the
    // runtime reads when it opens).
    let file = VdtFile::from_bytes(bytes.clone()).unwrap();
    let directory = file.directory().to_vec();
    let root_child = {
        let mut probe = runtime(&bytes, CornerTracking::Incidence);
        probe.cut_mut().store_mut().load_children(0).unwrap();
        probe.cut().node(0).first_child
    };
    let page_of = |id: u32| {
        directory
            .iter()
            .rposition(|p| p.first_node.get() <= id)
            .unwrap()
    };
    let mut bad = page_of(root_child);
    if bad == 0 {
        bad = 1; // The root's children share its page: corrupt the next page instead.
    }
    let entry = &directory[bad];
    let at = entry.offset.get() as usize + entry.compressed_length.get() as usize / 2;
    bytes[at] ^= 0x5A;
    let bad_nodes = entry.first_node.get()..entry.first_node.get() + entry.node_count.get();

    let mut runtime = background(&bytes, 2);
    let mut errors = Vec::new();
    let mut rng = Rng(5);
    for _ in 0..10 {
        let viewpoint = Viewpoint::Camera(random_camera(&mut rng, center, radius * 0.5));
        for _ in 0..3 {
            runtime
                .adjust(&viewpoint, &no_backface(), Goal::Threshold(0.5))
                .expect("the runtime goes on past a page it cannot read");
            runtime.wait_for_pages();
            errors.extend(runtime.take_page_errors());
        }
        for id in bad_nodes.clone() {
            assert_eq!(
                runtime.cut().state(id),
                NodeState::Inactive,
                "node {id} of the unreadable page entered the cut"
            );
        }
    }
    assert_eq!(errors.len(), 1, "{errors:?}");
    let message = errors[0].to_string();
    assert!(message.contains(&format!("page {bad}")), "{message}");
}

/// The most pages any boundary node's path from the root passes through: how many page
/// levels the cut descends.
fn page_depth(runtime: &Runtime) -> usize {
    let cut = runtime.cut();
    let source = cut.store().source();
    let first_nodes: Vec<u32> = source
        .directory()
        .iter()
        .map(|entry| entry.first_node.get())
        .collect();
    let page_of = |id: u32| first_nodes.partition_point(|&first| first <= id) - 1;
    let mut deepest = 0;
    for id in cut.boundary() {
        let (mut n, mut pages, mut page) = (id, 1, page_of(id));
        while n != vds_runtime::NIL {
            if page_of(n) != page {
                page = page_of(n);
                pages += 1;
            }
            n = cut.node(n).parent;
        }
        deepest = deepest.max(pages);
    }
    deepest
}

/// The loader looks ahead: a page it decodes has the pages below it that the cut will reach
/// asked for at once, so after the first adjust asks for the root's children the cut's whole
/// descent arrives without waiting for adjusts, and the second adjust settles the cut
/// however many page levels it descends (without looking ahead: one adjust per level).
#[test]
fn pages_below_arrive_without_an_adjust_per_level() {
    let mut scene = load("bunny.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let mut rng = Rng(5);
    let mut deepest = 0;
    for step in 0..6 {
        let viewpoint = Viewpoint::Camera(random_camera(&mut rng, center, radius));
        let mut runtime = background(&bytes, 1);
        let goal = Goal::Threshold(0.5);
        let rounds = settle(&mut runtime, &viewpoint, &no_backface(), goal);
        let depth = page_depth(&runtime);
        assert!(
            rounds <= 2,
            "step {step}: {rounds} adjusts to settle a cut {depth} pages deep"
        );
        deepest = deepest.max(depth);
    }
    assert!(
        deepest >= 4,
        "the cuts descend at most {deepest} pages: the test shows nothing"
    );
}

/// A page source whose reads wait while its gate is closed, counting them.
struct Gated {
    file: VdtFile<Vec<u8>>,
    gate: Arc<(Mutex<bool>, std::sync::Condvar)>,
    reads: Arc<std::sync::atomic::AtomicUsize>,
}

impl PageSource for Gated {
    fn header(&self) -> &Header {
        self.file.header()
    }
    fn directory(&self) -> &[PageEntry] {
        self.file.directory()
    }
    fn read_page_into(&self, index: u32, page: &mut Page) -> Result<(), VdtError> {
        let (open, opened) = &*self.gate;
        let mut guard = open.lock().unwrap();
        while !*guard {
            guard = opened.wait(guard).unwrap();
        }
        drop(guard);
        self.reads.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        self.file.read_page_into(index, page)
    }
}

/// A [`Gated`] source's gate: open while true.
type Gate = Arc<(Mutex<bool>, std::sync::Condvar)>;

/// A rank-tracking runtime loading `bytes` on one background thread through a [`Gated`]
/// source, with its gate and its count of reads.
fn gated(bytes: Vec<u8>) -> (Runtime, Gate, Arc<std::sync::atomic::AtomicUsize>) {
    let gate = Arc::new((Mutex::new(true), std::sync::Condvar::new()));
    let reads = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let source = Gated {
        file: VdtFile::from_bytes(bytes).unwrap(),
        gate: Arc::clone(&gate),
        reads: Arc::clone(&reads),
    };
    let runtime = Runtime::with_loading(
        Box::new(source),
        CornerTracking::Ranks,
        Loading::Background { threads: 1 },
    )
    .unwrap();
    (runtime, gate, reads)
}

/// A camera close in front of a model of `center` and `radius`, looking at it.
fn close_up(center: [f32; 3], radius: f32) -> vds_runtime::Camera {
    vds_runtime::Camera {
        eye: [center[0], center[1], center[2] + 1.5 * radius],
        target: center,
        up: [0.0, 1.0, 0.0],
        fov_y_degrees: 60.0,
        width: 800,
        height: 600,
        near: 0.01 * radius,
    }
}

/// A page asked for by a node that no longer asks for it (the camera turned away) is taken
/// back before a worker reaches it: it is not pending any more, and it is never read.
#[test]
fn pages_no_node_asks_for_any_more_are_not_read() {
    let mut scene = load("bunny.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let (mut runtime, gate, reads) = gated(bytes);
    let _open_on_drop = OpenOnDrop(Arc::clone(&gate));
    let close = close_up(center, radius);
    let viewpoint = Viewpoint::Camera(close);
    // A coarse cut first, spread over several pages, so that refining it asks for many.
    settle(
        &mut runtime,
        &viewpoint,
        &no_backface(),
        Goal::Threshold(8.0),
    );
    *gate.0.lock().unwrap() = false;
    let read_before = reads.load(std::sync::atomic::Ordering::SeqCst);
    let goal = Goal::Threshold(0.5);
    runtime.adjust(&viewpoint, &no_backface(), goal).unwrap();
    let asked = runtime.pending_pages();
    assert!(
        asked > 1,
        "only {asked} pages asked for: the test shows nothing"
    );
    let away = vds_runtime::Camera {
        target: [center[0], center[1], center[2] + 3.0 * radius],
        ..close
    };
    let frame = runtime
        .adjust(&Viewpoint::Camera(away), &no_backface(), goal)
        .unwrap();
    assert_eq!(frame.stats.deferred_unfolds, 0, "a node still waits");
    assert_eq!(
        runtime.pending_pages(),
        0,
        "pages nobody waits for are pending"
    );
    *gate.0.lock().unwrap() = true;
    gate.1.notify_all();
    runtime.wait_for_pages();
    // Only the page a worker had taken before the camera turned; nothing below it (the
    // loader looks ahead with the turned view).
    let read = reads.load(std::sync::atomic::Ordering::SeqCst) - read_before;
    assert!(read <= 1, "{read} pages read of the {asked} taken back");
}

/// A node whose unfold waits for a page while the camera stays still is visited again when
/// the page arrives: still passes (threshold adjusts for an unmoved camera) visit only what
/// did not settle, and a waiting unfold has not. The settled cut is the synchronous one.
#[test]
fn an_unfold_waiting_while_the_camera_is_still_happens_when_its_page_arrives() {
    let mut scene = load("bunny.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let (mut runtime, gate, _) = gated(bytes.clone());
    let _open_on_drop = OpenOnDrop(Arc::clone(&gate));
    let camera = close_up(center, radius);
    let viewpoint = Viewpoint::Camera(camera);
    let criteria = no_backface();
    settle(&mut runtime, &viewpoint, &criteria, Goal::Threshold(8.0));
    *gate.0.lock().unwrap() = false;
    let goal = Goal::Threshold(0.5);
    // A new threshold, then the same camera and threshold again while the pages wait: the
    // second adjust is a still pass, and its nodes that wait have not settled.
    for _ in 0..2 {
        let frame = runtime.adjust(&viewpoint, &criteria, goal).unwrap();
        assert!(
            frame.stats.deferred_unfolds > 0,
            "no unfold waits: the test shows nothing"
        );
    }
    *gate.0.lock().unwrap() = true;
    gate.1.notify_all();
    runtime.wait_for_pages();
    settle(&mut runtime, &viewpoint, &criteria, goal);
    let mut synchronous = common::runtime(&bytes, CornerTracking::Ranks);
    synchronous
        .adjust(&viewpoint, &criteria, Goal::Threshold(8.0))
        .unwrap();
    synchronous.adjust(&viewpoint, &criteria, goal).unwrap();
    assert_eq!(
        runtime.cut().boundary(),
        synchronous.cut().boundary(),
        "the settled cut differs from the synchronous one"
    );
}
