//! Headless runs: a camera path rendered offscreen, one PNG and one row of figures per frame.
//! What CI and benchmarks use; the same simplifier, uploads and pipeline as the window.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use vds_render::{CutPipeline, CutUpdate, Gpu, GpuCut, Hit, Offscreen, PartLook, Style};
use vds_runtime::CameraPath;

use crate::model::Model;
use crate::simplify::{AdjustFigures, AsyncSimplifier, Batch, Settings, Simplifier, fingerprint};

/// What a headless run does.
pub struct Headless {
    /// The cameras.
    pub path: CameraPath,
    /// Where PNGs go (`frame-00000.png`, ...); none: render without writing.
    pub out: Option<PathBuf>,
    /// Where the per-frame CSV goes.
    pub stats: Option<PathBuf>,
    /// Threshold or budget and criteria.
    pub settings: Settings,
    /// Look.
    pub style: Style,
    /// Simplify on a separate thread (frames show whatever complete adjusts are queued).
    pub asynchronous: bool,
    /// Draw the original mesh every frame instead of the cut.
    pub brute_force: bool,
    /// Check every cut and that every rendered frame shows exactly one adjust's cut.
    pub verify: bool,
    /// Stop adjusting after this frame and keep drawing the frozen cut along the path (the
    /// paper's "what did VDS do" views).
    pub freeze_after: Option<usize>,
    /// How each part is drawn (colour, hidden, picked), by part id.
    pub part_looks: Vec<PartLook>,
    /// Pixels (x, y; y down) to pick on the first frame.
    pub probes: Vec<(u32, u32)>,
    /// A PNG file for the first frame alone.
    pub first_image: Option<PathBuf>,
}

/// What a headless run returns.
pub struct Run {
    /// One row per frame.
    pub rows: Vec<FrameRow>,
    /// What the first frame shows at each of [`Headless::probes`].
    pub hits: Vec<Option<Hit>>,
}

/// One row of the per-frame table.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameRow {
    /// Frame index.
    pub frame: usize,
    /// The adjust behind this frame's newest applied batch (0 when none arrived).
    pub adjust: AdjustFigures,
    /// Bytes uploaded before this frame.
    pub upload_bytes: u64,
    /// GPU time of the draw, where timestamp queries exist.
    pub gpu_ms: Option<f64>,
    /// CPU time of the frame: simplification (when synchronous), uploads, draw and readback.
    pub cpu_frame_ms: f64,
    /// Triangles drawn (slots, free ones included).
    pub drawn_slots: u32,
    /// Batches applied before this frame.
    pub batches: usize,
}

const CSV_HEADER: &str = "frame,adjust_ms,upload_bytes,gpu_ms,cpu_frame_ms,active_triangles,added,removed,changed,drawn_slots,batches,pages_resident,pages_pending,resident_bytes,pages_loaded,pages_evicted,effective_threshold";

impl FrameRow {
    fn csv(&self) -> String {
        format!(
            "{},{:.4},{},{},{:.4},{},{},{},{},{},{},{},{},{},{},{},{}",
            self.frame,
            self.adjust.adjust_ms,
            self.upload_bytes,
            self.gpu_ms.map_or(String::new(), |g| format!("{g:.4}")),
            self.cpu_frame_ms,
            self.adjust.active_triangles,
            self.adjust.added,
            self.adjust.removed,
            self.adjust.changed,
            self.drawn_slots,
            self.batches,
            self.adjust.pages_resident,
            self.adjust.pages_pending,
            self.adjust.resident_bytes,
            self.adjust.pages_loaded,
            self.adjust.pages_evicted,
            self.adjust
                .effective_threshold
                .map_or_else(String::new, |t| format!("{t}")),
        )
    }
}

/// A CPU copy of the slot array, kept in verify mode to fingerprint what the GPU holds.
#[derive(Default)]
struct Mirror {
    slots: Vec<[u32; 4]>,
    /// The node each GPU vertex holds.
    vertex_nodes: Vec<u32>,
    /// The rank map of a rank-tracked cut (no blocks: slots hold vertices).
    rank_blocks: Vec<u32>,
    rank_words: Vec<u32>,
}

impl Mirror {
    fn apply(&mut self, update: &CutUpdate) {
        self.slots
            .resize(update.slot_count as usize, vds_render::update::EMPTY_SLOT);
        for (first, contents) in &update.slots {
            // A merged batch may hold slots that a later one cut off (the cut compacts its
            // slot array as it shrinks): those are no longer drawn.
            let first = (*first as usize).min(self.slots.len());
            let contents = &contents[..contents.len().min(self.slots.len() - first)];
            self.slots[first..first + contents.len()].copy_from_slice(contents);
        }
        self.vertex_nodes
            .resize(update.vertex_count as usize, u32::MAX);
        for ((first, _), nodes) in update.nodes.iter().zip(&update.vertex_nodes) {
            let first = *first as usize;
            self.vertex_nodes[first..first + nodes.len()].copy_from_slice(nodes);
        }
        self.rank_blocks
            .resize(update.rank_block_count as usize, u32::MAX);
        let words = (update.rank_word_count as usize).max(self.rank_words.len());
        self.rank_words.resize(words, u32::MAX);
        for (into, runs) in [
            (&mut self.rank_blocks, &update.rank_blocks),
            (&mut self.rank_words, &update.rank_words),
        ] {
            for (first, values) in runs {
                let first = *first as usize;
                into[first..first + values.len()].copy_from_slice(values);
            }
        }
    }

    /// The slots as the cut's nodes: `[corner node, corner node, corner node, part]`.
    fn triangles(&self) -> impl Iterator<Item = [u32; 4]> + '_ {
        self.slots.iter().map(|&slot| {
            if slot == vds_render::update::EMPTY_SLOT {
                slot
            } else {
                let node = |corner: u32| {
                    let v = if self.rank_blocks.is_empty() {
                        corner
                    } else {
                        vds_render::ranks::vertex_of_rank(
                            &self.rank_blocks,
                            &self.rank_words,
                            corner,
                        )
                    };
                    self.vertex_nodes
                        .get(v as usize)
                        .copied()
                        .unwrap_or(u32::MAX)
                };
                [node(slot[0]), node(slot[1]), node(slot[2]), slot[3]]
            }
        })
    }
}

/// Runs `headless` over `model` and returns the rows and the first frame's picks.
pub fn run_model(mut model: Model, headless: &Headless) -> Result<Run> {
    // Errors of the simplifier (a page that fails to load or decode) name the model.
    let name = model.name.clone();
    let gpu = Gpu::headless()?;
    let pipeline = CutPipeline::new(&gpu, vds_render::target_format());
    let first = headless
        .path
        .cameras
        .first()
        .context("the camera path is empty")?;
    let target = Offscreen::new(&gpu, first.width, first.height);
    if let Some(out) = &headless.out {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    }
    let mut csv = match &headless.stats {
        Some(path) => {
            let mut file = std::io::BufWriter::new(
                std::fs::File::create(path)
                    .with_context(|| format!("creating {}", path.display()))?,
            );
            writeln!(file, "{CSV_HEADER}")
                .with_context(|| format!("writing {}", path.display()))?;
            Some(file)
        }
        None => None,
    };

    let mut rows = Vec::new();
    let mut hits = Vec::new();
    let probe = |gpu_cut: &GpuCut, camera: &vds_runtime::Camera| -> Result<Vec<Option<Hit>>> {
        headless
            .probes
            .iter()
            .map(|&(x, y)| {
                vds_render::pick(&gpu, gpu_cut, &pipeline, camera, &headless.style, x, y)
                    .map_err(anyhow::Error::from)
            })
            .collect()
    };
    if headless.brute_force {
        let mesh = model
            .mesh
            .take()
            .context("brute force needs the original mesh")?;
        let mut gpu_cut = GpuCut::new(&gpu);
        gpu_cut.set_parts(&gpu, &pipeline, &headless.part_looks);
        let update = CutUpdate::whole_mesh(&mesh.positions, &mesh.triangles, &mesh.triangle_parts);
        let upload = gpu_cut.apply(&gpu, &pipeline, &update)?;
        for (i, camera) in headless.path.cameras.iter().enumerate() {
            let start = Instant::now();
            gpu_cut.set_frame(&gpu, camera, &headless.style);
            let gpu_ms = target.render(&gpu, &gpu_cut, &pipeline)?;
            let image = target.read(&gpu)?;
            if i == 0 {
                hits = probe(&gpu_cut, camera)?;
            }
            let row = FrameRow {
                frame: i,
                upload_bytes: if i == 0 { upload } else { 0 },
                gpu_ms,
                cpu_frame_ms: start.elapsed().as_secs_f64() * 1e3,
                drawn_slots: gpu_cut.slot_count(),
                adjust: AdjustFigures {
                    active_triangles: mesh.triangles.len() as u32,
                    ..Default::default()
                },
                batches: 0,
            };
            finish_frame(headless, &image, &row, csv.as_mut())?;
            rows.push(row);
        }
        return Ok(Run { rows, hits });
    }

    let mut gpu_cut = GpuCut::new(&gpu);
    gpu_cut.set_parts(&gpu, &pipeline, &headless.part_looks);
    let mut mirror = headless.verify.then(Mirror::default);
    let mut simplifier = Some(Simplifier::new(model.runtime, headless.verify));
    let asynchronous = headless
        .asynchronous
        .then(|| AsyncSimplifier::spawn(simplifier.take().expect("not yet moved")));
    let mut last_figures = AdjustFigures::default();
    for (i, camera) in headless.path.cameras.iter().enumerate() {
        let start = Instant::now();
        let frozen = headless.freeze_after.is_some_and(|f| i > f);
        let batches: Vec<Batch> = match (&mut simplifier, &asynchronous) {
            _ if frozen => Vec::new(),
            (Some(simplifier), _) => vec![
                simplifier
                    .step(camera, &headless.settings)
                    .with_context(|| name.clone())?,
            ],
            (None, Some(worker)) => {
                worker.request(*camera, headless.settings);
                let mut queued = worker.drain().with_context(|| name.clone())?;
                if i == 0 && queued.is_empty() {
                    // Nothing to show yet on the very first frame: wait for the first cut.
                    queued.push(worker.wait().with_context(|| name.clone())?);
                }
                queued
            }
            (None, None) => unreachable!("one of the two modes"),
        };
        // All queued batches go up together at the start of the frame.
        let mut upload_bytes = 0;
        // Without a new batch, the cut on screen is the last one: same counts, no work.
        let mut figures = AdjustFigures {
            adjust_ms: 0.0,
            added: 0,
            removed: 0,
            changed: 0,
            ..last_figures
        };
        for batch in &batches {
            upload_bytes += gpu_cut.apply(&gpu, &pipeline, &batch.update)?;
            figures = batch.figures;
            last_figures = batch.figures;
            if let (Some(mirror), Some(expected)) = (&mut mirror, batch.fingerprint) {
                mirror.apply(&batch.update);
                let got = fingerprint(mirror.triangles());
                anyhow::ensure!(
                    got == expected,
                    "frame {i}: the renderer's triangles differ from the cut after the adjust"
                );
            }
        }
        gpu_cut.set_frame(&gpu, camera, &headless.style);
        let gpu_ms = target.render(&gpu, &gpu_cut, &pipeline)?;
        let image = target.read(&gpu)?;
        if i == 0 {
            hits = probe(&gpu_cut, camera)?;
        }
        let row = FrameRow {
            frame: i,
            adjust: figures,
            upload_bytes,
            gpu_ms,
            cpu_frame_ms: start.elapsed().as_secs_f64() * 1e3,
            drawn_slots: gpu_cut.slot_count(),
            batches: batches.len(),
        };
        finish_frame(headless, &image, &row, csv.as_mut())?;
        rows.push(row);
    }
    if let (Some(file), Some(path)) = (&mut csv, &headless.stats) {
        file.flush()
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(Run { rows, hits })
}

fn finish_frame(
    headless: &Headless,
    image: &vds_render::Image,
    row: &FrameRow,
    csv: Option<&mut std::io::BufWriter<std::fs::File>>,
) -> Result<()> {
    if let Some(out) = &headless.out {
        let path = out.join(format!("frame-{:05}.png", row.frame));
        image.write_png(&path)?;
    }
    if let (Some(path), 0) = (&headless.first_image, row.frame) {
        image.write_png(path)?;
    }
    if let (Some(csv), Some(path)) = (csv, &headless.stats) {
        writeln!(csv, "{}", row.csv()).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
