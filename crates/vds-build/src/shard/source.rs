//! What a plan reads of a welded, snapped scene ([`PlanScene`]): its positions, in memory
//! (the plan's passes and the shards' inputs look them up at random), and its triangles in
//! runs, so that a scene whose triangles stay on disk ([`vds_import::SpilledScene`]) is planned
//! as a scene in memory is.

use vds_import::{Scene, SpilledScene};

use super::ShardError;

/// Triangles per run of an in-memory scene.
const RUN: usize = 1 << 16;

/// What [`PlanScene::for_each_triangle_run`] calls for each run: the index of the run's
/// first triangle, its triangles and their parts.
pub type TriangleRun<'a> = dyn FnMut(u64, &[[u32; 3]], &[u32]) -> Result<(), ShardError> + 'a;

/// A welded scene snapped to the plan's grid, as the plan and the shards' inputs read it.
pub trait PlanScene: Sync {
    /// Welded positions.
    fn positions(&self) -> &[[f32; 3]];
    /// Number of triangles.
    fn triangle_count(&self) -> u64;
    /// Calls `each(first, triangles, parts)` for runs of the triangles in order, `first`
    /// being the index of the run's first triangle.
    fn for_each_triangle_run(&self, each: &mut TriangleRun<'_>) -> Result<(), ShardError>;
}

impl PlanScene for Scene {
    fn positions(&self) -> &[[f32; 3]] {
        &self.positions
    }

    fn triangle_count(&self) -> u64 {
        self.triangles.len() as u64
    }

    fn for_each_triangle_run(&self, each: &mut TriangleRun<'_>) -> Result<(), ShardError> {
        for (k, (triangles, parts)) in self
            .triangles
            .chunks(RUN)
            .zip(self.triangle_parts.chunks(RUN))
            .enumerate()
        {
            each((k * RUN) as u64, triangles, parts)?;
        }
        Ok(())
    }
}

impl PlanScene for SpilledScene {
    fn positions(&self) -> &[[f32; 3]] {
        &self.positions
    }

    fn triangle_count(&self) -> u64 {
        self.triangle_count
    }

    fn for_each_triangle_run(&self, each: &mut TriangleRun<'_>) -> Result<(), ShardError> {
        SpilledScene::for_each_triangle_run(self, each, ShardError::Import)
    }
}
