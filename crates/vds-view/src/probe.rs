//! What a pick and a measurement report, in the words a review uses: the part's id, name,
//! assembly path and size, the world position on screen, and for measurements the original
//! vertices the picks snap to (the full-resolution surface, whatever the level of detail on
//! screen) and their distance. Shared by the headless JSON and the window's panel.

use anyhow::{Context, Result};
use serde_json::{Value, json};
use vds_render::Hit;
use vds_runtime::PageSource;
use vds_runtime::nearest::{NearestLeaf, nearest_leaf};

use crate::parts::Parts;

/// The JSON of a pick at `pixel`: null fields where the background shows.
pub fn pick_json(parts: &Parts, pixel: (u32, u32), hit: Option<Hit>) -> Value {
    let Some(hit) = hit else {
        return json!({ "x": pixel.0, "y": pixel.1, "part": null });
    };
    let part = parts.parts.get(hit.part as usize);
    json!({
        "x": pixel.0,
        "y": pixel.1,
        "part": hit.part,
        "name": part.map(|p| p.name.clone()),
        "path": part.map(|p| p.path.clone()),
        "triangles": part.map(|p| p.triangles),
        "world": hit.world,
    })
}

/// A measurement between two picks: each snapped to its nearest original vertex.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    /// The snapped ends.
    pub ends: [NearestLeaf; 2],
    /// The distance between them.
    pub distance: f32,
}

impl Measurement {
    /// The measurement between two snapped ends.
    pub fn between(a: NearestLeaf, b: NearestLeaf) -> Measurement {
        let distance = (0..3)
            .map(|k| f64::from(a.position[k] - b.position[k]).powi(2))
            .sum::<f64>()
            .sqrt() as f32;
        Measurement {
            ends: [a, b],
            distance,
        }
    }
}

/// The original vertex nearest a picked point.
pub fn snap(source: &dyn PageSource, hit: Hit) -> Result<Option<NearestLeaf>> {
    nearest_leaf(source, hit.world).context("snapping a measured point to the model's vertices")
}

/// Snaps both picked points to the original vertices nearest them.
pub fn measure(source: &dyn PageSource, hits: [Hit; 2]) -> Result<Option<Measurement>> {
    let (Some(a), Some(b)) = (snap(source, hits[0])?, snap(source, hits[1])?) else {
        return Ok(None);
    };
    Ok(Some(Measurement::between(a, b)))
}

/// The JSON of a measurement between `pixels`: both picks, their snapped vertices and the
/// distance (null when either pixel shows the background).
pub fn measure_json(
    parts: &Parts,
    source: &dyn PageSource,
    pixels: [(u32, u32); 2],
    hits: [Option<Hit>; 2],
) -> Result<Value> {
    let picks = [
        pick_json(parts, pixels[0], hits[0]),
        pick_json(parts, pixels[1], hits[1]),
    ];
    let (Some(a), Some(b)) = (hits[0], hits[1]) else {
        return Ok(json!({ "picks": picks, "distance": null }));
    };
    let Some(m) = measure(source, [a, b])? else {
        return Ok(json!({ "picks": picks, "distance": null }));
    };
    Ok(json!({
        "picks": picks,
        "snapped": [m.ends[0].position, m.ends[1].position],
        "snap_exact": m.ends[0].exact && m.ends[1].exact,
        "distance": m.distance,
    }))
}
