//! Exact measurements of a cut against the original vertices: how far, in pixels, each
//! visible original vertex appears from where its current proxy is drawn. Used by the tests
//! (the threshold guarantee) and by `vds-cut --json`.

use glam::Vec3;
use vds_format::VdtError;

use crate::cut::Cut;
use crate::store::NodeStore;
use crate::view::View;

/// The original vertex positions by leaf rank. Loads every page.
pub fn leaf_positions(store: &NodeStore) -> Result<Vec<[f32; 3]>, VdtError> {
    let mut positions = vec![[0.0; 3]; store.vertex_count() as usize];
    let mut seen = vec![false; positions.len()];
    // Page by page, through the reader's checks, keeping none: the model may not fit.
    store.for_each_page(|page| {
        for record in page.nodes.iter().filter(|r| r.child_count == 0) {
            let rank = record.leaf_begin.get() as usize;
            if let Some(p) = positions.get_mut(rank) {
                *p = record.proxy.map(|c| c.get());
                seen[rank] = true;
            }
        }
    })?;
    match seen.iter().position(|&s| !s) {
        Some(rank) => Err(VdtError::invalid(
            "tree",
            format!("no leaf holds vertex {rank}"),
        )),
        None => Ok(positions),
    }
}

/// The result of [`screen_deviation`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Deviation {
    /// The largest distance in pixels between a visible vertex's image and its proxy's.
    pub max_px: f64,
    /// The original vertex it was measured at (leaf rank), if any vertex is visible.
    pub worst_rank: Option<u32>,
    /// How many original vertices lie in the view frustum.
    pub visible_vertices: u64,
}

/// For every original vertex inside `view`'s frustum (and, when `only` is given, marked in
/// it), the on-screen distance between its projection and its current proxy's projection
/// (both in double precision); the largest. A proxy behind the eye counts as infinitely far.
pub fn screen_deviation(
    cut: &Cut,
    view: &View,
    positions: &[[f32; 3]],
    only: Option<&[bool]>,
) -> Deviation {
    let mut deviation = Deviation::default();
    for (rank, &p) in positions.iter().enumerate() {
        let v = Vec3::from(p);
        if !view.contains(v) || only.is_some_and(|only| !only[rank]) {
            continue;
        }
        deviation.visible_vertices += 1;
        let proxy = Vec3::from(cut.node(cut.current_proxy_node(rank as u32)).proxy);
        let distance = match (view.project(v), view.project(proxy)) {
            (Some(a), Some(b)) => (a[0] - b[0]).hypot(a[1] - b[1]),
            _ => f64::INFINITY,
        };
        if distance > deviation.max_px || deviation.worst_rank.is_none() {
            deviation.max_px = deviation.max_px.max(distance);
            deviation.worst_rank = Some(rank as u32);
        }
    }
    deviation
}

/// The largest object-space distance between an original vertex and its current proxy.
pub fn object_deviation(cut: &Cut, positions: &[[f32; 3]]) -> f32 {
    positions
        .iter()
        .enumerate()
        .map(|(rank, &p)| {
            let proxy = Vec3::from(cut.node(cut.current_proxy_node(rank as u32)).proxy);
            Vec3::from(p).distance(proxy)
        })
        .fold(0.0, f32::max)
}

/// Per leaf rank: whether the vertex has an incident triangle that faces `eye` or is seen
/// edge-on — the vertices backface simplification must not fold away. Zero-area triangles
/// count as facing (they bound no normal, so no cone test folds them). Reads every page,
/// keeps none.
pub fn facing_vertices(
    store: &NodeStore,
    positions: &[[f32; 3]],
    eye: Vec3,
) -> Result<Vec<bool>, VdtError> {
    let mut facing = vec![false; positions.len()];
    store.for_each_page(|page| {
        for triangle in &page.triangles {
            let ranks = triangle.corners.map(|c| c.get() as usize);
            let Some(p) = ranks
                .iter()
                .map(|&r| positions.get(r).map(|&p| Vec3::from(p)))
                .collect::<Option<Vec<_>>>()
            else {
                continue; // The reader keeps corners below the vertex count.
            };
            let normal = (p[1] - p[0]).cross(p[2] - p[0]);
            if normal.dot(eye - p[0]) >= 0.0 || normal == Vec3::ZERO {
                for r in ranks {
                    facing[r] = true;
                }
            }
        }
    })?;
    Ok(facing)
}
