//! Simplification for the viewer, synchronous or asynchronous (Luebke & Erikson §4.4, and
//! Luebke's dissertation §6.2).
//!
//! In asynchronous mode a SIMPLIFY thread owns the runtime: it waits for the latest camera,
//! adjusts the cut, and queues the resulting [`Batch`] (a complete [`CutUpdate`]: one adjust's
//! changes). The RENDER thread never waits for it: at the start of each frame it applies every
//! batch queued so far, in order, as one upload. A frame therefore always shows the cut after
//! some complete adjust — never half of one — and when the camera jumps the scene stays coarse
//! for a few frames instead of the frame time spiking.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::sync::mpsc::{Receiver, Sender, TryRecvError};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use vds_render::{CutUpdate, RankMirror, VertexPool};
use vds_runtime::{Camera, CornerTracking, Criteria, Goal, Runtime, Viewpoint};

/// What the cut is asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// Threshold or budget.
    pub goal: Goal,
    /// Criteria.
    pub criteria: Criteria,
}

/// Figures of one adjust.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AdjustFigures {
    /// Adjust time in milliseconds (including collecting the update).
    pub adjust_ms: f64,
    /// Active triangles after it.
    pub active_triangles: u32,
    /// Active nodes after it.
    pub active_nodes: u32,
    /// Triangles added, removed, re-cornered.
    pub added: u32,
    /// See `added`.
    pub removed: u32,
    /// See `added`.
    pub changed: u32,
    /// Nodes folded and unfolded (with rank tracking, which counts no triangle whose corners
    /// moved, the only sign of a cut that changed without adding or removing triangles).
    pub nodes_changed: u32,
    /// Pages resident.
    pub pages_resident: u32,
    /// Pages asked of the background loader and not yet arrived.
    pub pages_pending: u32,
    /// Pages decoded since the model opened.
    pub pages_loaded: u64,
    /// Pages evicted since the model opened.
    pub pages_evicted: u64,
    /// Bytes the runtime holds (decoded pages, page tables, the cut's arrays).
    pub resident_bytes: u64,
    /// The memory budget those bytes are held to.
    pub budget_bytes: u64,
    /// The threshold the adjust used (threshold mode): the requested one, or more while the
    /// budget cannot hold the cut.
    pub effective_threshold: Option<f32>,
}

/// One adjust's worth of GPU updates.
#[derive(Debug, Clone)]
pub struct Batch {
    /// The update.
    pub update: CutUpdate,
    /// The adjust's figures.
    pub figures: AdjustFigures,
    /// With verification on: a fingerprint of the whole active triangle set after this
    /// adjust, to compare with what the renderer's mirror holds after applying the batch.
    pub fingerprint: Option<u64>,
}

/// A fingerprint of a set of slot contents (`[corner, corner, corner, part]`, empty slots
/// ignored), independent of which slot holds what.
pub fn fingerprint(slots: impl Iterator<Item = [u32; 4]>) -> u64 {
    let mut triangles: Vec<[u32; 4]> = slots
        .filter(|s| *s != vds_render::update::EMPTY_SLOT)
        .collect();
    triangles.sort_unstable();
    let mut hasher = DefaultHasher::new();
    triangles.hash(&mut hasher);
    hasher.finish()
}

/// What the GPU mirror holds, kept beside the runtime to turn its changes into updates.
enum GpuMirror {
    /// Slots of vertices (incidence or lazy corner tracking).
    Slots(VertexPool),
    /// Slots of original ranks and a rank → vertex map (rank tracking); `None` until the
    /// first adjust uploads the whole cut.
    Ranks(Option<Box<RankMirror>>),
}

/// The runtime and how to turn its adjusts into batches.
pub struct Simplifier {
    runtime: Runtime,
    mirror: GpuMirror,
    verify: bool,
}

impl Simplifier {
    /// A simplifier over `runtime`; `verify` checks the cut after every adjust and
    /// fingerprints it (slow: for tests).
    pub fn new(runtime: Runtime, verify: bool) -> Simplifier {
        let mirror = match runtime.cut().tracking() {
            CornerTracking::Ranks => GpuMirror::Ranks(None),
            _ => GpuMirror::Slots(VertexPool::new()),
        };
        Simplifier {
            runtime,
            mirror,
            verify,
        }
    }

    /// The runtime.
    pub fn runtime(&self) -> &Runtime {
        &self.runtime
    }

    /// Adjusts for `camera` and returns the batch.
    pub fn step(&mut self, camera: &Camera, settings: &Settings) -> anyhow::Result<Batch> {
        let start = Instant::now();
        let frame = self.runtime.adjust(
            &Viewpoint::Camera(*camera),
            &settings.criteria,
            settings.goal,
        )?;
        // A page the loader could not read is said once; its nodes stay folded.
        for error in self.runtime.take_page_errors() {
            eprintln!("vds-view: {error}");
        }
        let cut = self.runtime.cut_mut();
        let update = match &mut self.mirror {
            GpuMirror::Slots(pool) => pool.collect(cut, &frame.changes),
            GpuMirror::Ranks(Some(mirror)) => mirror.collect(cut, &frame.changes),
            GpuMirror::Ranks(started @ None) => {
                started.insert(Box::new(RankMirror::new())).everything(cut)
            }
        };
        let adjust_ms = start.elapsed().as_secs_f64() * 1e3;
        let fingerprint = if self.verify {
            self.runtime
                .cut_mut()
                .check()
                .map_err(|e| anyhow::anyhow!("inconsistent cut: {e}"))?;
            let cut = self.runtime.cut_mut();
            let slots: Vec<[u32; 4]> = cut
                .active_triangles()
                .iter()
                .map(|t| {
                    let part = cut.store().triangle_part(t.triangle);
                    [t.corners[0], t.corners[1], t.corners[2], part]
                })
                .collect();
            Some(fingerprint(slots.into_iter()))
        } else {
            None
        };
        let cut = self.runtime.cut();
        Ok(Batch {
            update,
            figures: AdjustFigures {
                adjust_ms,
                active_triangles: cut.active_triangle_count(),
                active_nodes: cut.active_node_count(),
                added: frame.changes.added,
                removed: frame.changes.removed,
                changed: frame.changes.changed,
                nodes_changed: frame.stats.unfolds + frame.stats.folds,
                pages_resident: frame.memory.pages_resident,
                pages_pending: frame.memory.pages_pending,
                pages_loaded: frame.memory.pages_loaded,
                pages_evicted: frame.memory.pages_evicted,
                resident_bytes: frame.memory.resident_bytes,
                budget_bytes: frame.memory.budget_bytes,
                effective_threshold: frame.effective_threshold,
            },
            fingerprint,
        })
    }
}

struct Shared {
    request: Mutex<Request>,
    wake: Condvar,
}

#[derive(Default)]
struct Request {
    latest: Option<(Camera, Settings)>,
    stop: bool,
}

/// The SIMPLIFY thread and the queue between it and the renderer.
pub struct AsyncSimplifier {
    shared: Arc<Shared>,
    batches: Receiver<anyhow::Result<Batch>>,
    thread: Option<JoinHandle<Simplifier>>,
}

impl AsyncSimplifier {
    /// Starts the thread; it owns `simplifier` from now on.
    pub fn spawn(mut simplifier: Simplifier) -> AsyncSimplifier {
        let shared = Arc::new(Shared {
            request: Mutex::new(Request::default()),
            wake: Condvar::new(),
        });
        let (sender, batches): (Sender<anyhow::Result<Batch>>, _) = std::sync::mpsc::channel();
        let thread_shared = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("vds simplify".into())
            .spawn(move || {
                loop {
                    let (camera, settings) = {
                        let mut request = thread_shared.request.lock().expect("request lock");
                        loop {
                            if request.stop {
                                return simplifier;
                            }
                            if let Some(latest) = request.latest.take() {
                                break latest;
                            }
                            request = thread_shared.wake.wait(request).expect("request lock");
                        }
                    };
                    let batch = simplifier.step(&camera, &settings);
                    let failed = batch.is_err();
                    if sender.send(batch).is_err() || failed {
                        return simplifier;
                    }
                }
            })
            .expect("spawning the simplify thread");
        AsyncSimplifier {
            shared,
            batches,
            thread: Some(thread),
        }
    }

    /// Asks for a cut for `camera`, replacing any request not yet taken (latest wins).
    pub fn request(&self, camera: Camera, settings: Settings) {
        let mut request = self.shared.request.lock().expect("request lock");
        request.latest = Some((camera, settings));
        self.shared.wake.notify_one();
    }

    /// Every batch queued so far, in order, without waiting.
    pub fn drain(&self) -> anyhow::Result<Vec<Batch>> {
        let mut batches = Vec::new();
        loop {
            match self.batches.try_recv() {
                Ok(batch) => batches.push(batch?),
                Err(TryRecvError::Empty) => return Ok(batches),
                Err(TryRecvError::Disconnected) => {
                    anyhow::bail!("the simplify thread stopped")
                }
            }
        }
    }

    /// Waits for the next batch.
    pub fn wait(&self) -> anyhow::Result<Batch> {
        self.batches
            .recv()
            .map_err(|_| anyhow::anyhow!("the simplify thread stopped"))?
    }
}

impl AsyncSimplifier {
    /// Stops the thread (after the adjust in progress) and hands the simplifier back with the
    /// batches still queued, which the renderer must apply to stay in step with the cut.
    pub fn stop(mut self) -> (Option<Simplifier>, Vec<Batch>) {
        let simplifier = self.halt();
        let queued = self.batches.try_iter().filter_map(Result::ok).collect();
        (simplifier, queued)
    }

    fn halt(&mut self) -> Option<Simplifier> {
        if let Ok(mut request) = self.shared.request.lock() {
            request.stop = true;
        }
        self.shared.wake.notify_one();
        self.thread.take().and_then(|thread| thread.join().ok())
    }
}

impl Drop for AsyncSimplifier {
    fn drop(&mut self) {
        self.halt();
    }
}
