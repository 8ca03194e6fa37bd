//! The memory budget: the store never holds more than its budget, eviction never removes a
//! page the cut needs (checked after every frame with a budget that forces constant
//! eviction), no adjust reads a page under background loading while pages come and go, and
//! once the budget holds the cut again the screen-space bound holds again. The process-level
//! bound (anonymous resident memory under a budget, along an orbit and a fly-through) runs
//! `vds-cut`, so that the test harness's own memory (the scene it built) does not count.

mod common;

use std::process::Command;
use std::sync::{Arc, Mutex};
use std::thread::ThreadId;

use common::*;
use vds_format::{Header, Page, PageEntry, VdtError, VdtFile};
use vds_runtime::{
    CameraPath, CornerTracking, Criteria, Goal, Loading, PageSource, Runtime, Viewpoint, measure,
};

/// Bytes the store holds with every page of `bytes` resident.
fn decoded_size(bytes: &[u8]) -> u64 {
    let mut full = runtime(bytes, CornerTracking::Incidence);
    full.set_memory_budget(u64::MAX);
    full.load_every_page().unwrap();
    full.memory().resident_bytes
}

fn paths(center: [f32; 3], radius: f32, frames: u32) -> Vec<(&'static str, CameraPath)> {
    vec![
        ("orbit", CameraPath::orbit(center, radius, frames, 640, 360)),
        (
            "fly",
            CameraPath::fly_through(center, radius, frames, 640, 360),
        ),
    ]
}

#[test]
fn a_tiny_budget_evicts_constantly_and_never_a_page_the_cut_needs() {
    let (bytes, center, radius) = generated(60_000);
    let decoded = decoded_size(&bytes);
    let budget = decoded / 8;
    for tracking in [
        CornerTracking::Incidence,
        CornerTracking::Lazy,
        CornerTracking::Ranks,
    ] {
        for (name, path) in paths(center, radius, 40) {
            let mut runtime = runtime(&bytes, tracking);
            runtime.set_memory_budget(budget);
            for (i, camera) in path.cameras.iter().enumerate() {
                let frame = runtime
                    .adjust(
                        &Viewpoint::Camera(*camera),
                        &Criteria::default(),
                        Goal::Threshold(1.0),
                    )
                    .unwrap();
                runtime
                    .cut_mut()
                    .check()
                    .unwrap_or_else(|e| panic!("{name} frame {i}: {e}"));
                let memory = frame.memory;
                assert!(
                    memory.resident_bytes <= budget || runtime.cut().store().over_budget_pinned(),
                    "{name} frame {i}: {} bytes held over a budget of {budget}",
                    memory.resident_bytes
                );
                assert!(frame.effective_threshold.unwrap() >= 1.0);
            }
            assert!(
                runtime.memory().pages_evicted > 0,
                "{name}: a budget of an eighth of the model never evicted"
            );
        }
    }
}

#[test]
fn the_budget_is_hard_when_the_cut_fits() {
    // The cut at 4 px fits in half of the model: the budget is never exceeded, because pages
    // that do not fit are refused rather than installed and the rest is evicted.
    let (bytes, center, radius) = generated(60_000);
    let budget = decoded_size(&bytes) / 2;
    let mut runtime = runtime(&bytes, CornerTracking::Incidence);
    runtime.set_memory_budget(budget);
    let mut most = 0;
    for camera in &CameraPath::fly_through(center, radius, 60, 640, 360).cameras {
        let frame = runtime
            .adjust(
                &Viewpoint::Camera(*camera),
                &Criteria::default(),
                Goal::Threshold(4.0),
            )
            .unwrap();
        most = most.max(frame.memory.resident_bytes);
    }
    assert!(
        most <= budget,
        "{most} bytes held over a budget of {budget}"
    );
}

#[test]
fn when_the_cut_does_not_fit_the_threshold_rises_and_falls_back_when_it_does() {
    let (bytes, center, radius) = generated(60_000);
    let decoded = decoded_size(&bytes);
    let mut positions_runtime = runtime(&bytes, CornerTracking::Incidence);
    let positions = positions_runtime.leaf_positions().unwrap();
    let camera = CameraPath::fly_through(center, radius, 8, 640, 360).cameras[0];
    let viewpoint = Viewpoint::Camera(camera);
    let criteria = Criteria {
        backface: false,
        ..Criteria::default()
    };
    let t = 0.5;
    let mut runtime = runtime(&bytes, CornerTracking::Incidence);
    runtime.set_memory_budget(decoded / 20);
    let mut raised = 1.0f32;
    for _ in 0..60 {
        let frame = runtime
            .adjust(&viewpoint, &criteria, Goal::Threshold(t))
            .unwrap();
        raised = raised.max(frame.effective_threshold.unwrap() / t);
    }
    assert!(raised > 1.0, "a twentieth of the model held a 0.5 px cut");
    let squeezed = runtime.cut().active_triangle_count();
    // A budget that holds the whole model: the threshold comes back down to what was asked.
    runtime.set_memory_budget(u64::MAX);
    let mut settled = None;
    for round in 0..400 {
        let frame = runtime
            .adjust(&viewpoint, &criteria, Goal::Threshold(t))
            .unwrap();
        if frame.effective_threshold == Some(t) && frame.changes.dirty_slots.is_empty() {
            settled = Some(round);
            break;
        }
    }
    assert!(
        settled.is_some(),
        "the effective threshold never came back to {t}"
    );
    runtime.cut_mut().check().unwrap();
    assert!(runtime.cut().active_triangle_count() > squeezed);
    let deviation = measure::screen_deviation(runtime.cut(), &camera.view(), &positions, None);
    assert!(
        deviation.max_px <= f64::from(t) * (1.0 + 1e-4) + 1e-4,
        "{} px > {t} px once the budget held the cut",
        deviation.max_px
    );
}

/// A page source that records which thread read each page.
struct Recording {
    file: VdtFile<Vec<u8>>,
    /// Each read's page and the thread that read it.
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

#[test]
fn background_loading_under_eviction_never_reads_on_the_adjusting_thread() {
    let (bytes, center, radius) = generated(60_000);
    let budget = decoded_size(&bytes) / 8;
    let reads = Arc::new(Mutex::new(Vec::new()));
    let source = Recording {
        file: VdtFile::from_bytes(bytes.clone()).unwrap(),
        reads: Arc::clone(&reads),
    };
    let mut runtime = Runtime::with_loading(
        Box::new(source),
        CornerTracking::Incidence,
        Loading::Background { threads: 2 },
    )
    .unwrap();
    runtime.set_memory_budget(budget);
    let opened = reads.lock().unwrap().len();
    let me = std::thread::current().id();
    for (_, path) in paths(center, radius, 60) {
        for (k, camera) in path.cameras.iter().enumerate() {
            let frame = runtime
                .adjust(
                    &Viewpoint::Camera(*camera),
                    &Criteria::default(),
                    Goal::Threshold(1.0),
                )
                .unwrap();
            runtime.cut_mut().check().unwrap();
            assert!(
                frame.memory.resident_bytes <= budget || runtime.cut().store().over_budget_pinned(),
                "{} > {budget}: {:?}, cut {}",
                frame.memory.resident_bytes,
                frame.memory,
                runtime.cut().own_bytes()
            );
            // Every other frame lets loading settle, so that the pages the paths need arrive
            // (and push others out) whatever the loader's threads get of the machine; the
            // frames between adjust while pages are on their way.
            if k % 2 == 1 {
                runtime.wait_for_pages();
            }
        }
    }
    let reads = reads.lock().unwrap();
    assert!(
        reads[opened..].iter().all(|&(_, thread)| thread != me),
        "an adjust read a page itself"
    );
    // A page installed twice was evicted in between (reads alone do not show it: a page
    // fetched ahead or refused is read and dropped).
    let mut pages: Vec<u32> = reads.iter().map(|&(page, _)| page).collect();
    pages.sort_unstable();
    pages.dedup();
    let memory = runtime.memory();
    assert!(
        memory.pages_evicted > 0 && memory.pages_loaded > pages.len() as u64,
        "{} pages evicted, {} installed, {} distinct pages read",
        memory.pages_evicted,
        memory.pages_loaded,
        pages.len()
    );
}

/// The numbers of column `name` of `vds-cut`'s statistics.
fn column(csv: &str, name: &str) -> Vec<u64> {
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let at = header.iter().position(|&h| h == name).unwrap();
    lines
        .map(|l| l.split(',').nth(at).unwrap().parse().unwrap())
        .collect()
}

#[test]
fn rss_stays_within_the_budget_along_an_orbit_and_a_fly_through() {
    // A model whose decoded tree is at least 8 times the budget, replayed by `vds-cut` with
    // background loading: its anonymous resident memory, read per frame from
    // /proc/self/status, stays within the budget and 64 MiB.
    let (bytes, _, _) = generated(400_000);
    let decoded = decoded_size(&bytes);
    let page_count = VdtFile::from_bytes(bytes.clone())
        .unwrap()
        .directory()
        .len() as u64;
    let budget: u64 = 2 << 20;
    assert!(
        decoded >= 8 * budget,
        "the model decodes to only {decoded} bytes"
    );
    let dir = std::env::temp_dir().join(format!("vds-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("generated.vdt");
    std::fs::write(&file, &bytes).unwrap();
    let (mut loaded_bytes, mut evicted_pages) = (0, 0);
    // Whether pages arrive under background loading depends on what the machine gives its
    // threads, so a synchronous replay makes sure the pages that pass through the store are
    // more than its budget whatever the timing.
    let replays = [
        ("--orbit", "background"),
        ("--fly", "background"),
        ("--fly", "synchronous"),
    ];
    for (path, loading) in replays {
        let stats = dir.join(format!("stats{path}-{loading}.csv"));
        let output = Command::new(env!("CARGO_BIN_EXE_vds-cut"))
            .arg(&file)
            .args([
                path,
                "--frames",
                "90",
                "--threshold",
                "1",
                "--loading",
                loading,
            ])
            .args(["--memory-budget", "2MiB", "--pace-ms", "5", "--stats"])
            .arg(&stats)
            .output()
            .unwrap();
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        let csv = std::fs::read_to_string(&stats).unwrap();
        let rss = column(&csv, "rss_anon_bytes");
        let held = column(&csv, "resident_bytes");
        let evicted = *column(&csv, "pages_evicted").last().unwrap();
        let loaded = *column(&csv, "pages_loaded").last().unwrap();
        let worst = *rss.iter().max().unwrap();
        assert!(
            worst <= budget + (64 << 20),
            "{path} {loading}: RssAnon reached {worst} bytes with a budget of {budget}"
        );
        assert!(
            held.iter().all(|&h| h <= budget),
            "{path} {loading}: the store went over its budget"
        );
        loaded_bytes += loaded * decoded / page_count;
        evicted_pages += evicted;
    }
    // The paths must have gone through more than the budget holds, or they tested nothing.
    assert!(
        loaded_bytes > budget && evicted_pages > 0,
        "only {loaded_bytes} bytes of pages loaded, {evicted_pages} evicted"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
