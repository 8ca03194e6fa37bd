//! The page encoding of version 4: nodes and triangles as columns of small integers
//! (LEB128 varints, zig-zag for signed deltas), each column in its own stream so zstd sees
//! similar bytes together. Positions are grid coordinates delta-coded against the previous
//! node; leaf ids are coded relative to the owning node's leaf range; leaves carry no bounds
//! (a leaf never unfolds, so no runtime test reads them).
//!
//! Where one column mixes bytes of different statistics, it is split so that zstd's entropy
//! coder sees each kind alone: a leaf coordinate's nearly uniform low byte apart from its
//! small high part, inner proxies (a few units each) apart from leaves, cone angles apart
//! from axes.
//!
//! Encoding widens bounds for what it quantises (proxy, sphere centre, cone axis), so decoded
//! bounds stay conservative. Decoding checks every length and value; it never reads past a
//! stream or trusts a count it has not bounded.

use zerocopy::FromZeros;
use zerocopy::little_endian::{F32, U16, U32};

use crate::VdtError;
use crate::grid::Grid;
use crate::layout::{FLAG_TWO_SIDED_CONE, NO_NODE, NodeRecord, TriangleRecord};

/// The streams of a page, in order (see `docs/format.md`).
pub(crate) const STREAMS: usize = 16;

// Stream numbers.
const CHILD_COUNT: usize = 0;
const PARENT: usize = 1;
const FIRST_CHILD: usize = 2;
const DEPTH: usize = 3;
const LEAF_BEGIN: usize = 4;
const LEAF_COUNT: usize = 5;
const SUBTRI_COUNT: usize = 6;
const LEAF_LOW: usize = 7;
const LEAF_HIGH: usize = 8;
const INNER_POSITION: usize = 9;
const BOUNDS: usize = 10;
const CONE_AXIS: usize = 11;
const CONE_ANGLE: usize = 12;
const SURFACE: usize = 13;
const CORNERS: usize = 14;
const PART: usize = 15;

/// The axis prediction of a node whose parent lies in another page: the octahedral centre.
const NO_AXIS: [u8; 2] = [128, 128];

/// Bit of a child-count byte (stream 0) marking an inner node's cone as two-sided.
const TWO_SIDED_BIT: u8 = 0x80;

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

fn unzigzag(v: u64) -> i64 {
    ((v >> 1) as i64) ^ -((v & 1) as i64)
}

/// The byte difference `value − predicted`, taken modulo 256 and zig-zag coded, so that
/// small steps either way become small bytes.
fn byte_step(value: u8, predicted: u8) -> u8 {
    let d = value.wrapping_sub(predicted) as i8;
    ((d << 1) ^ (d >> 7)) as u8
}

/// The inverse of [`byte_step`].
fn unbyte_step(step: u8, predicted: u8) -> u8 {
    let d = ((step >> 1) as i8) ^ -((step & 1) as i8);
    predicted.wrapping_add(d as u8)
}

/// Octahedral encoding of a unit vector in two bytes (about 1° of error, which the encoder
/// adds to the cone's half-angle).
fn octahedral(axis: [f32; 3]) -> [u8; 2] {
    let [x, y, z] = axis.map(f64::from);
    let l1 = x.abs() + y.abs() + z.abs();
    let (mut u, mut v) = if l1 > 0.0 {
        (x / l1, y / l1)
    } else {
        (0.0, 0.0)
    };
    if z < 0.0 {
        let (pu, pv) = (u, v);
        u = (1.0 - pv.abs()) * pu.signum();
        v = (1.0 - pu.abs()) * pv.signum();
    }
    [u, v].map(|c| (((c.clamp(-1.0, 1.0) + 1.0) * 0.5 * 255.0).round()) as u8)
}

fn unoctahedral(e: [u8; 2]) -> [f32; 3] {
    // In f32: the decoder runs this once per inner node, and the encoder measures the
    // angle to exactly this result, so the widening covers whatever f32 rounding does.
    let [u, v] = e.map(|c| f32::from(c) * (2.0 / 255.0) - 1.0);
    let z = 1.0 - u.abs() - v.abs();
    let (x, y) = if z < 0.0 {
        ((1.0 - v.abs()) * u.signum(), (1.0 - u.abs()) * v.signum())
    } else {
        (u, v)
    };
    // |x| + |y| + |z| = 1, so the length is at least 1/√3: the division is safe.
    let inverse = 1.0 / (x * x + y * y + z * z).sqrt();
    [x * inverse, y * inverse, z * inverse]
}

/// The angle between two vectors, with `libm`'s `atan2` (the same bits on every machine, unlike
/// the system library's, which picks its code by CPU): it decides how far a cone is widened,
/// so it reaches the file's bytes.
fn angle(a: [f32; 3], b: [f32; 3]) -> f64 {
    let [a, b] = [a, b].map(|v| v.map(f64::from));
    let c = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let sin = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    libm::atan2(sin, a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
}

/// An inner node's surface error is stored as a fraction of its stored error radius on a
/// scale of half octaves: level `u` in `1..=SURFACE_LEVELS` stands for `2^(−(16 − u)/2)` of
/// the radius (the whole radius down to 1/181 of it), 0 for none; values round up.
const SURFACE_LEVELS: u8 = 16;

/// The share of the error radius each surface-error level stands for, built at compile
/// time. Powers of ½ are exact and odd steps take one multiplication by 1/√2, so encoder and
/// decoder agree on every machine.
const SURFACE_SHARES: [f64; SURFACE_LEVELS as usize + 1] = {
    let mut shares = [0.0; SURFACE_LEVELS as usize + 1];
    let mut u = 1;
    while u <= SURFACE_LEVELS as usize {
        let steps = SURFACE_LEVELS as usize - u;
        let mut share = 1.0;
        let mut k = 0;
        while k < steps / 2 {
            share *= 0.5;
            k += 1;
        }
        if steps % 2 == 1 {
            share *= std::f64::consts::FRAC_1_SQRT_2;
        }
        shares[u] = share;
        u += 1;
    }
    shares
};

/// The share of the error radius that surface-error level `u` (at most [`SURFACE_LEVELS`])
/// stands for.
fn surface_share(u: u8) -> f64 {
    SURFACE_SHARES[usize::from(u)]
}

/// The smallest level whose share is at least `share` (> 0), or the whole radius.
fn surface_level_at_least(share: f64) -> u8 {
    (1..SURFACE_LEVELS)
        .find(|&u| surface_share(u) >= share)
        .unwrap_or(SURFACE_LEVELS)
}

/// The surface-error level predicted from a node's cone half-angle units: planes whose
/// normals spread by a half-angle `α` lie about `sin α / 2` of the radius from a proxy
/// among them (an empty cone predicts the middle level). Coded as a byte step from this,
/// the levels take a little less than on their own. The decoder asks once per inner node,
/// so the 256 answers are computed once.
fn predicted_surface_level(angle_units: u8) -> u8 {
    static PREDICTIONS: std::sync::OnceLock<[u8; 256]> = std::sync::OnceLock::new();
    PREDICTIONS.get_or_init(|| {
        std::array::from_fn(|units| {
            if units == usize::from(EMPTY_CONE) {
                return SURFACE_LEVELS / 2;
            }
            let half = (units as f64 / ANGLE_UNITS * std::f64::consts::PI)
                .min(std::f64::consts::FRAC_PI_2);
            // `libm`'s sine, not the system library's: the prediction reaches the file's
            // bytes.
            surface_level_at_least(0.5 * libm::sin(half))
        })
    })[usize::from(angle_units)]
}

/// The surface-error level of an inner node whose surface error is `surface` before its
/// proxy moved by `moved` to where it is stored, with `error_radius` the radius as stored
/// (which already holds that move; a plane's distance changes by at most the move): the
/// smallest level at or above the share. A NaN takes the whole radius, which always holds.
fn surface_byte(surface: f32, moved: f64, error_radius: f64) -> u8 {
    let surface = f64::from(surface) + moved;
    if surface.is_nan() {
        return SURFACE_LEVELS;
    }
    if surface <= 0.0 || error_radius <= 0.0 {
        return 0;
    }
    surface_level_at_least(surface / error_radius)
}

/// Half-angles are stored in units of π / 254, rounded up; 255 marks the empty cone.
const ANGLE_UNITS: f64 = 254.0;
const EMPTY_CONE: u8 = u8::MAX;

/// Sphere centres are stored relative to the proxy in units of a 32nd of the node's error
/// radius (at least one grid step): the centre lies within a few error radii of the proxy,
/// so each offset takes a byte, and the rounding is added to the sphere's radius.
const CENTRE_UNITS_PER_RADIUS: u64 = 32;

fn centre_unit(error_units: u64) -> u64 {
    (error_units / CENTRE_UNITS_PER_RADIUS).max(1)
}

/// Inner proxies are stored in units of a 32nd of their (unwidened) error radius, at least
/// one grid step: the runtime's error test already tolerates the error radius, so a proxy
/// moved by a few percent of it costs nothing visible, and saves a byte per coordinate.
fn proxy_unit(base_error_units: u64) -> u64 {
    (base_error_units / 32).max(1)
}

/// The error radius that holds after an inner proxy was stored in `unit`s: each coordinate
/// moves less than one unit (rounded to nearest, or one step back onto the grid), so the
/// proxy moves less than √3 units; one more step absorbs rounding.
fn widened_error(base_error_units: u64, unit: u64) -> u64 {
    base_error_units + (unit as f64 * 3f64.sqrt()).ceil() as u64 + 1
}

fn distance(a: [f32; 3], b: [f32; 3]) -> f64 {
    (0..3)
        .map(|k| (f64::from(a[k]) - f64::from(b[k])).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Working arrays of [`encode_page_into`], kept by a caller that encodes page after page, so
/// that the streams stop growing (and copying themselves) after the first pages.
#[derive(Default)]
pub struct EncodeScratch {
    streams: [Vec<u8>; STREAMS],
    /// The grid coordinates as stored (inner proxies are coarser than their exact ones).
    stored_q: Vec<[i64; 3]>,
    /// The cone axes as stored (octahedral bytes; leaves hold a placeholder), the prediction
    /// of their children's.
    stored_axis: Vec<[u8; 2]>,
}

/// Encodes one page: `nodes` with ids from `first_node`, and their subtris `triangles`.
/// Leaf positions must lie on the grid. (The writer encodes with [`encode_page_into`].)
#[cfg(test)]
pub fn encode_page(
    grid: &Grid,
    first_node: u32,
    nodes: &[NodeRecord],
    triangles: &[TriangleRecord],
) -> Result<Vec<u8>, VdtError> {
    let mut out = Vec::new();
    encode_page_into(
        &mut EncodeScratch::default(),
        grid,
        first_node,
        nodes,
        triangles,
        &mut out,
    )?;
    Ok(out)
}

/// [`encode_page`] into `out` (cleared first), with working arrays kept in `scratch`.
pub fn encode_page_into(
    scratch: &mut EncodeScratch,
    grid: &Grid,
    first_node: u32,
    nodes: &[NodeRecord],
    triangles: &[TriangleRecord],
    out: &mut Vec<u8>,
) -> Result<(), VdtError> {
    let EncodeScratch {
        streams: s,
        stored_q,
        stored_axis,
    } = scratch;
    for stream in s.iter_mut() {
        stream.clear();
    }
    stored_q.clear();
    stored_axis.clear();
    let page = first_node..first_node + nodes.len() as u32;
    let mut previous_q = [0i64; 3];
    // Where the next inner node's children are expected: right after the previous inner
    // node's (pages are breadth-first within), or right after the first inner node itself.
    let mut expected_child: Option<i64> = None;
    for (k, n) in nodes.iter().enumerate() {
        let id = first_node + k as u32;
        let proxy = n.proxy.map(|c| c.get());
        let exact_q = grid.quantize(proxy);
        // The child count, and for an inner node whose cone is two-sided the flag in bit 7.
        let two_sided = n.child_count > 0 && n.flags & FLAG_TWO_SIDED_CONE != 0;
        s[CHILD_COUNT].push(n.child_count | if two_sided { TWO_SIDED_BIT } else { 0 });
        // A parent in this page is implied by its child range, and a sibling of the previous
        // node shares its parent; either way the depth and first leaf follow. Only the first
        // node of a sibling group whose parent lies in another page spells them out.
        let parent = n.parent.get();
        let previous = k.checked_sub(1).map(|p| &nodes[p]);
        if page.contains(&parent) || previous.is_some_and(|p| p.parent.get() == parent) {
            put_varint(&mut s[PARENT], 0);
        } else {
            put_varint(
                &mut s[PARENT],
                if parent == NO_NODE {
                    0
                } else {
                    u64::from(id - parent)
                },
            );
            let (depth, leaf) = previous.map_or((0, 0), |p| {
                (i64::from(p.depth.get()), i64::from(p.leaf_end.get()))
            });
            put_varint(&mut s[DEPTH], zigzag(i64::from(n.depth.get()) - depth));
            put_varint(
                &mut s[LEAF_BEGIN],
                zigzag(i64::from(n.leaf_begin.get()) - leaf),
            );
        }
        // A leaf supports one vertex, so it owns no subtri: only inner nodes store a count.
        if n.child_count > 0 {
            put_varint(&mut s[SUBTRI_COUNT], u64::from(n.subtri_count.get()));
        } else if n.subtri_count.get() != 0 {
            return Err(VdtError::invalid(
                format!("node {id}"),
                "a leaf with subtris",
            ));
        }
        // Positions are predicted by the previous node (usually the previous sibling), or
        // for a first child by its parent's proxy, which lies in the same small cell.
        let prediction = if page.contains(&parent)
            && nodes[(parent - first_node) as usize].first_child.get() == id
        {
            stored_q[(parent - first_node) as usize]
        } else {
            previous_q
        };
        // Leaves are exact; an inner proxy is stored in units of a 32nd of its error radius,
        // and its error radius grows by the most that can move it (see `proxy_unit`).
        let base_error = if n.child_count == 0 {
            0
        } else {
            u64::from(grid.units_up(f64::from(n.error_radius.get())))
        };
        let unit = if n.child_count == 0 {
            1
        } else {
            proxy_unit(base_error)
        };
        let mut q = [0u32; 3];
        for a in 0..3 {
            let exact = i64::from(exact_q[a]);
            let steps = position_steps(exact, prediction[a], unit as i64);
            let step = zigzag(steps);
            if n.child_count == 0 {
                s[LEAF_LOW].push(step as u8);
                put_varint(&mut s[LEAF_HIGH], step >> 8);
            } else {
                put_varint(&mut s[INNER_POSITION], step);
            }
            q[a] = (prediction[a] + steps * unit as i64) as u32;
        }
        previous_q = q.map(i64::from);
        stored_q.push(previous_q);
        let stored = grid.dequantize(q);
        if n.child_count == 0 {
            stored_axis.push(NO_AXIS);
            if stored != proxy {
                return Err(VdtError::invalid(
                    format!("node {id}"),
                    "leaf position is not on the file's grid",
                ));
            }
            continue;
        }
        let first_child = i64::from(n.first_child.get());
        let predicted = expected_child.unwrap_or(i64::from(id) + 1);
        put_varint(&mut s[FIRST_CHILD], zigzag(first_child - predicted));
        expected_child = Some(first_child + i64::from(n.child_count));
        put_varint(
            &mut s[LEAF_COUNT],
            u64::from(n.leaf_end.get() - n.leaf_begin.get()),
        );
        // Bounds, widened by what quantising the proxy, centre and axis moved.
        let moved = distance(proxy, stored);
        let error_units = widened_error(base_error, unit);
        // Holds for every tree a build makes; a tree from damaged input (a radius past the
        // grid's largest, a NaN) is refused rather than written with a bound that does not hold.
        let bounded =
            error_units as f64 * f64::from(grid.step) >= f64::from(n.error_radius.get()) + moved;
        if !bounded {
            return Err(VdtError::invalid(
                format!("node {id}"),
                "error radius that the file's grid cannot bound",
            ));
        }
        put_varint(&mut s[BOUNDS], base_error);
        let surface_level = surface_byte(
            n.surface_error.get(),
            moved,
            error_units as f64 * f64::from(grid.step),
        );
        let unit = centre_unit(error_units);
        let centre = [n.sphere[0].get(), n.sphere[1].get(), n.sphere[2].get()];
        let mut centre_q = [0u32; 3];
        for a in 0..3 {
            let offset = (f64::from(centre[a]) - f64::from(stored[a])) / f64::from(grid.step);
            let steps = crate::grid::round_half_away(offset / unit as f64);
            // Keep the decoded centre on the grid; whatever clamping costs is widened below.
            let lowest = -(i64::from(q[a]) / unit as i64);
            let highest = (i64::from(crate::grid::GRID_STEPS) - i64::from(q[a])) / unit as i64;
            let steps = steps.clamp(lowest, highest);
            put_varint(&mut s[BOUNDS], zigzag(steps));
            centre_q[a] = (i64::from(q[a]) + steps * unit as i64) as u32;
        }
        let centre_moved = distance(centre, grid.dequantize(centre_q));
        // The radius in the same coarse units, rounded up.
        let radius_units = u64::from(grid.units_up(f64::from(n.sphere[3].get()) + centre_moved));
        put_varint(&mut s[BOUNDS], radius_units.div_ceil(unit));
        let axis = [n.cone[0].get(), n.cone[1].get(), n.cone[2].get()];
        let half_angle = f64::from(n.cone[3].get());
        let (encoded, units) = if half_angle < 0.0 {
            ([0u8; 2], EMPTY_CONE)
        } else {
            let e = octahedral(axis);
            let widened = half_angle + angle(axis, unoctahedral(e));
            let units = (widened / std::f64::consts::PI * ANGLE_UNITS).ceil() + 1.0;
            (e, units.min(ANGLE_UNITS) as u8)
        };
        // Axes as steps from the parent's (normals vary smoothly down the tree).
        let predicted = if page.contains(&parent) {
            stored_axis[(parent - first_node) as usize]
        } else {
            NO_AXIS
        };
        stored_axis.push(encoded);
        s[CONE_AXIS].push(byte_step(encoded[0], predicted[0]));
        s[CONE_AXIS].push(byte_step(encoded[1], predicted[1]));
        s[CONE_ANGLE].push(units);
        s[SURFACE].push(byte_step(surface_level, predicted_surface_level(units)));
    }
    // Triangles: corners relative to the owning node's first leaf, parts as deltas.
    let mut t = 0usize;
    let mut previous_part = 0i64;
    for n in nodes {
        let begin = i64::from(n.leaf_begin.get());
        for tri in &triangles[t..t + n.subtri_count.get() as usize] {
            for c in tri.corners {
                put_varint(&mut s[CORNERS], zigzag(i64::from(c.get()) - begin));
            }
            put_varint(
                &mut s[PART],
                zigzag(i64::from(tri.part.get()) - previous_part),
            );
            previous_part = i64::from(tri.part.get());
        }
        t += n.subtri_count.get() as usize;
    }
    out.clear();
    out.reserve(4 * STREAMS + s.iter().map(Vec::len).sum::<usize>());
    for stream in s.iter() {
        out.extend_from_slice(&(stream.len() as u32).to_le_bytes());
    }
    for stream in s.iter() {
        out.extend_from_slice(stream);
    }
    Ok(())
}

/// The steps of `unit` from `prediction` that come nearest `exact`, kept on the grid.
fn position_steps(exact: i64, prediction: i64, unit: i64) -> i64 {
    // With a unit of one step (every leaf), the step is the exact difference and the stored
    // coordinate the exact one, on the grid: no division, rounding or clamp.
    if unit == 1 {
        return exact - prediction;
    }
    let steps = crate::grid::round_half_away((exact - prediction) as f64 / unit as f64);
    if (0..=i64::from(crate::grid::GRID_STEPS)).contains(&(prediction + steps * unit)) {
        steps
    } else {
        back_on_grid(prediction, steps, unit)
    }
}

/// Steps back towards the grid from a rounding that left it. (Apart and cold: as loops in
/// [`position_steps`], the compiler made them one division per coordinate of every node.)
#[cold]
fn back_on_grid(prediction: i64, mut steps: i64, unit: i64) -> i64 {
    while prediction + steps * unit > i64::from(crate::grid::GRID_STEPS) {
        steps -= 1;
    }
    while prediction + steps * unit < 0 {
        steps += 1;
    }
    steps
}

/// Rewrites the parent step of a page's first node (the first value of its parent stream)
/// from `old` to `new`, as encoding the page with another numbering of nodes outside it would
/// have written it. A region's first page is the only page of the region whose bytes depend
/// on where the region lands in the file: its first node's parent is the region root, in the
/// file's top, and every other link inside the region is a difference of two region ids.
pub(crate) fn rebase_first_parent(
    raw: &[u8],
    old: u64,
    new: u64,
    out: &mut Vec<u8>,
) -> Result<(), String> {
    let length = |k: usize| -> Result<usize, String> {
        let bytes = raw
            .get(4 * k..4 * k + 4)
            .ok_or("page too short for its stream table")?;
        Ok(u32::from_le_bytes(bytes.try_into().expect("4 bytes")) as usize)
    };
    let start = 4 * STREAMS + length(CHILD_COUNT)?;
    let parent_length = length(PARENT)?;
    let mut stream = Stream {
        bytes: raw
            .get(start..start + parent_length)
            .ok_or("stream runs past the page")?,
        at: 0,
    };
    let value = stream.varint().ok_or("the page has no first parent")?;
    if value != old {
        return Err(format!("the first parent step is {value}, not {old}"));
    }
    let old_bytes = stream.at;
    let mut new_bytes = Vec::with_capacity(10);
    put_varint(&mut new_bytes, new);
    let rebased = (parent_length - old_bytes + new_bytes.len()) as u32;
    out.clear();
    out.reserve(raw.len() + new_bytes.len());
    out.extend_from_slice(&raw[..4 * PARENT]);
    out.extend_from_slice(&rebased.to_le_bytes());
    out.extend_from_slice(&raw[4 * PARENT + 4..start]);
    out.extend_from_slice(&new_bytes);
    out.extend_from_slice(&raw[start + old_bytes..]);
    Ok(())
}

/// A decoded grid coordinate, if it lies on the grid.
fn grid_coordinate(v: i64) -> Option<u32> {
    u32::try_from(v)
        .ok()
        .filter(|&c| c <= crate::grid::GRID_STEPS)
}

/// A bounds-checked reader of one stream.
struct Stream<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Stream<'_> {
    fn varint(&mut self) -> Option<u64> {
        // Most values fit in one byte.
        let first = *self.bytes.get(self.at)?;
        if first < 0x80 {
            self.at += 1;
            return Some(u64::from(first));
        }
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = *self.bytes.get(self.at)?;
            self.at += 1;
            v |= u64::from(b & 0x7F) << shift;
            if b < 0x80 {
                return Some(v);
            }
        }
        None
    }

    /// The next `N` bytes.
    fn bytes<const N: usize>(&mut self) -> Option<[u8; N]> {
        let bytes = self.bytes.get(self.at..self.at + N)?;
        self.at += N;
        Some(bytes.try_into().expect("N bytes"))
    }

    /// The next three varints; three one-byte values (a leaf's position steps, nearly always)
    /// take one bounds check and one test.
    fn three_varints(&mut self) -> Option<[u64; 3]> {
        if let Some(&[a, b, c]) = self.bytes.get(self.at..self.at + 3)
            && (a | b | c) < 0x80
        {
            self.at += 3;
            return Some([a, b, c].map(u64::from));
        }
        Some([self.varint()?, self.varint()?, self.varint()?])
    }

    fn byte(&mut self) -> Option<u8> {
        let b = *self.bytes.get(self.at)?;
        self.at += 1;
        Some(b)
    }

    fn done(&self) -> bool {
        self.at == self.bytes.len()
    }
}

/// Where a page's records go, what the page holds, and the file's limits every record must
/// keep. As the reader's directory check guarantees, node ids `first_node + node_count` and
/// triangle indices `first_triangle + triangle_count` fit in 32 bits and the file holds the
/// page's nodes.
pub struct PageShape {
    /// Id of the first node.
    pub first_node: u32,
    /// Number of nodes.
    pub node_count: u32,
    /// Index of the first triangle.
    pub first_triangle: u32,
    /// Number of triangles.
    pub triangle_count: u32,
    /// Nodes in the whole file (child ids stay below).
    pub file_nodes: u64,
    /// Vertices (leaves) in the whole file (leaf ranges and corners stay below).
    pub file_vertices: u64,
    /// The deepest depth the header declares.
    pub max_depth: u32,
    /// Part names in the metadata (part ids stay below, or are 0 when there is none).
    pub parts: u64,
}

/// Working arrays of [`decode_page`], kept by the caller so that decoding page after page
/// allocates nothing.
#[derive(Default)]
pub struct Scratch {
    /// Parent of each node of the page whose parent is also in it (from the child ranges).
    parent_in_page: Vec<u32>,
    /// Each node's grid coordinates as stored: a first child's position is predicted by its
    /// parent's.
    stored_q: Vec<[u32; 3]>,
    /// Each node's cone axis bytes as stored: a child's are predicted by its parent's.
    stored_axis: Vec<[u8; 2]>,
}

/// Decodes a page encoded by [`encode_page`] into `nodes` and `triangles` (cleared first, so
/// a caller decoding many pages can reuse them).
///
/// It checks the encoding (lengths, ranges, no trailing bytes) and, as it goes, every record
/// against the file's limits in `shape`, so that what it returns passes
/// `VdtFile::validate_page` (a separate pass over the records cost a tenth of decoding):
/// - the root alone has no parent, and every parent id is below its child's: a parent in the
///   page was announced by an earlier node's child range, a parent delta is positive, and a
///   sibling's parent is checked to exist;
/// - child counts are at most 8, children come after their parent and exist;
/// - leaf ranges are non-empty and end within the file's vertices; depths stay within the
///   header's; subtri ranges lie in the page (they are consecutive from its first triangle
///   and add up to its triangle count);
/// - every float is finite and every radius non-negative: positions are at most
///   [`crate::grid::GRID_STEPS`] steps from the grid origin and radii fewer than 2³³ steps,
///   which the reader's grid check makes finite (`VdtFile` refuses a grid where they are
///   not); axes are unit vectors and half-angles at most π;
/// - corners are below the file's vertex count and parts below its part count.
pub fn decode_page(
    grid: &Grid,
    raw: &[u8],
    shape: &PageShape,
    scratch: &mut Scratch,
    nodes: &mut Vec<NodeRecord>,
    triangles: &mut Vec<TriangleRecord>,
) -> Result<(), String> {
    let PageShape {
        first_node,
        node_count,
        first_triangle,
        triangle_count,
        file_nodes,
        file_vertices,
        max_depth,
        parts: part_count,
    } = *shape;
    nodes.clear();
    triangles.clear();
    let table = raw
        .get(..4 * STREAMS)
        .ok_or("page too short for its stream table")?;
    let mut streams = Vec::with_capacity(STREAMS);
    let mut at = 4 * STREAMS;
    for k in 0..STREAMS {
        let length =
            u32::from_le_bytes(table[4 * k..4 * k + 4].try_into().expect("4 bytes")) as usize;
        let end = at
            .checked_add(length)
            .filter(|&e| e <= raw.len())
            .ok_or("stream runs past the page")?;
        streams.push(Stream {
            bytes: &raw[at..end],
            at: 0,
        });
        at = end;
    }
    if at != raw.len() {
        return Err("bytes after the last stream".into());
    }
    let bad = |what: &str| format!("stream ends early or holds a bad value ({what})");
    let f = |x: f32| F32::new(x);
    // Written in place: `push` would check capacity and store the length for every record.
    nodes.resize(node_count as usize, NodeRecord::new_zeroed());
    let Scratch {
        parent_in_page,
        stored_q,
        stored_axis,
    } = scratch;
    parent_in_page.clear();
    parent_in_page.resize(node_count as usize, NO_NODE);
    stored_q.clear();
    stored_q.reserve(node_count as usize);
    stored_axis.clear();
    stored_axis.reserve(node_count as usize);
    let mut previous_q = [0i64; 3];
    let mut subtri_begin = u64::from(first_triangle);
    let mut expected_child: Option<i64> = None;
    for k in 0..node_count {
        let id = first_node + k;
        let [
            child_counts,
            parents,
            first_children,
            depths,
            leaf_begins,
            leaf_counts,
            subtri_counts,
            leaf_low,
            leaf_high,
            inner_position,
            bounds,
            cone_axis,
            cone_angle,
            surface,
            ..,
        ] = &mut streams[..]
        else {
            unreachable!()
        };
        let count_byte = child_counts.byte().ok_or_else(|| bad("child count"))?;
        let two_sided = count_byte & TWO_SIDED_BIT != 0;
        let child_count = count_byte & !TWO_SIDED_BIT;
        if two_sided && child_count == 0 {
            return Err(bad("two-sided cone on a leaf"));
        }
        if child_count > 8 {
            return Err(bad("child count"));
        }
        let parent_delta = parents.varint().ok_or_else(|| bad("parent"))?;
        let mut prediction = previous_q;
        let previous = k.checked_sub(1).map(|i| &nodes[i as usize]);
        let in_page = parent_in_page[k as usize];
        let (parent, depth, leaf_begin) = if parent_delta == 0 && id != 0 && in_page != NO_NODE {
            let p = &nodes[(in_page - first_node) as usize];
            let depth = p.depth.get().checked_add(1).ok_or_else(|| bad("depth"))?;
            // The first child starts at its parent's first leaf, the others where the
            // previous sibling ends.
            let leaf_begin = if p.first_child.get() == id {
                prediction = stored_q[(in_page - first_node) as usize].map(i64::from);
                p.leaf_begin.get()
            } else {
                previous.ok_or_else(|| bad("leaf"))?.leaf_end.get()
            };
            (in_page, depth, leaf_begin)
        } else if parent_delta == 0 && id != 0 {
            // A sibling of the previous node, whose parent is in another page.
            let p = previous
                .filter(|p| p.parent.get() != NO_NODE)
                .ok_or_else(|| bad("parent"))?;
            (p.parent.get(), p.depth.get(), p.leaf_end.get())
        } else {
            let parent = if parent_delta == 0 {
                NO_NODE
            } else {
                u64::from(id)
                    .checked_sub(parent_delta)
                    .and_then(|p| u32::try_from(p).ok())
                    .ok_or_else(|| bad("parent"))?
            };
            let (depth, leaf) = previous.map_or((0, 0), |p| {
                (i64::from(p.depth.get()), i64::from(p.leaf_end.get()))
            });
            // Checked: a hostile varint may hold any 64-bit step.
            let depth = depths
                .varint()
                .and_then(|z| depth.checked_add(unzigzag(z)))
                .and_then(|d| u16::try_from(d).ok())
                .ok_or_else(|| bad("depth"))?;
            let leaf_begin = leaf_begins
                .varint()
                .and_then(|z| leaf.checked_add(unzigzag(z)))
                .and_then(|l| u32::try_from(l).ok())
                .ok_or_else(|| bad("leaf"))?;
            (parent, depth, leaf_begin)
        };
        if u32::from(depth) > max_depth {
            return Err(bad("depth beyond the header's"));
        }
        let subtri_index = u32::try_from(subtri_begin).map_err(|_| bad("subtris"))?;
        if child_count == 0 {
            // A leaf (most nodes): its position in whole grid steps, and nothing else.
            let lows = leaf_low.bytes::<3>().ok_or_else(|| bad("position"))?;
            let highs = leaf_high.three_varints().ok_or_else(|| bad("position"))?;
            let mut q = [0u32; 3];
            for a in 0..3 {
                let (low, high) = (lows[a], highs[a]);
                if high > u64::MAX >> 8 {
                    return Err(bad("position"));
                }
                let v = unzigzag(high << 8 | u64::from(low))
                    .checked_add(prediction[a])
                    .ok_or_else(|| bad("position"))?;
                previous_q[a] = v;
                q[a] = grid_coordinate(v).ok_or_else(|| bad("position"))?;
            }
            stored_q.push(q);
            stored_axis.push(NO_AXIS);
            let proxy = grid.dequantize(q);
            let leaf_end = leaf_begin
                .checked_add(1)
                .filter(|&end| u64::from(end) <= file_vertices)
                .ok_or_else(|| bad("leaf"))?;
            nodes[k as usize] = NodeRecord {
                parent: U32::new(parent),
                first_child: U32::new(NO_NODE),
                child_count,
                flags: 0,
                depth: U16::new(depth),
                leaf_begin: U32::new(leaf_begin),
                leaf_end: U32::new(leaf_end),
                subtri_begin: U32::new(subtri_index),
                subtri_count: U32::new(0),
                proxy: proxy.map(f),
                error_radius: f(0.0),
                surface_error: f(0.0),
                sphere: [proxy[0], proxy[1], proxy[2], 0.0].map(f),
                cone: [0.0, 0.0, 1.0, -1.0].map(f),
            };
            continue;
        }
        let subtri_count = u32::try_from(subtri_counts.varint().ok_or_else(|| bad("subtris"))?)
            .map_err(|_| bad("subtris"))?;
        // The error radius comes first, it sets the proxy's unit.
        let base_error = bounds
            .varint()
            .filter(|&u| u <= u64::from(u32::MAX))
            .ok_or_else(|| bad("bound"))?;
        let unit = proxy_unit(base_error) as i64;
        let mut q = [0u32; 3];
        for a in 0..3 {
            let step = inner_position.varint().ok_or_else(|| bad("position"))?;
            let v = unzigzag(step)
                .checked_mul(unit)
                .and_then(|d| d.checked_add(prediction[a]))
                .ok_or_else(|| bad("position"))?;
            previous_q[a] = v;
            q[a] = grid_coordinate(v).ok_or_else(|| bad("position"))?;
        }
        stored_q.push(q);
        let proxy = grid.dequantize(q);
        subtri_begin += u64::from(subtri_count);
        let predicted = expected_child.unwrap_or(i64::from(id) + 1);
        let first_child = unzigzag(first_children.varint().ok_or_else(|| bad("children"))?)
            .checked_add(predicted)
            .and_then(|c| u32::try_from(c).ok())
            .filter(|&c| c > id && u64::from(c) + u64::from(child_count) <= file_nodes)
            .ok_or_else(|| bad("children"))?;
        expected_child = Some(i64::from(first_child) + i64::from(child_count));
        for child in first_child..first_child.saturating_add(u32::from(child_count)) {
            if let Some(slot) = parent_in_page.get_mut(child.wrapping_sub(first_node) as usize) {
                *slot = id;
            }
        }
        let leaf_end = leaf_counts
            .varint()
            .filter(|&count| count > 0)
            .and_then(|count| u64::from(leaf_begin).checked_add(count))
            .filter(|&end| end <= file_vertices)
            .ok_or_else(|| bad("leaf count"))?;
        let error_units = widened_error(base_error, unit as u64);
        let error_radius = error_units as f32 * grid.step;
        let unit = centre_unit(error_units) as i64;
        let mut centre_q = [0u32; 3];
        for a in 0..3 {
            let steps = unzigzag(bounds.varint().ok_or_else(|| bad("sphere"))?);
            let v = steps
                .checked_mul(unit)
                .and_then(|d| d.checked_add(i64::from(q[a])))
                .ok_or_else(|| bad("sphere"))?;
            centre_q[a] = grid_coordinate(v).ok_or_else(|| bad("sphere"))?;
        }
        let centre = grid.dequantize(centre_q);
        let radius_units = bounds
            .varint()
            .and_then(|r| r.checked_mul(unit as u64))
            .filter(|&u| u <= u64::from(u32::MAX))
            .ok_or_else(|| bad("sphere"))?;
        let predicted = parent
            .checked_sub(first_node)
            .and_then(|p| stored_axis.get(p as usize))
            .copied()
            .unwrap_or(NO_AXIS);
        let mut axis_byte = |k: usize| {
            cone_axis
                .byte()
                .map(|b| unbyte_step(b, predicted[k]))
                .ok_or_else(|| bad("cone"))
        };
        let e = [axis_byte(0)?, axis_byte(1)?];
        stored_axis.push(e);
        let angle_units = cone_angle.byte().ok_or_else(|| bad("cone"))?;
        let surface_level = surface
            .byte()
            .map(|b| unbyte_step(b, predicted_surface_level(angle_units)))
            .filter(|&u| u <= SURFACE_LEVELS)
            .ok_or_else(|| bad("surface error"))?;
        // At most the error radius (a share of at most 1 of it).
        let surface_error = (f64::from(error_radius) * surface_share(surface_level))
            .min(f64::from(error_radius)) as f32;
        let axis = unoctahedral(e);
        let half = if angle_units == EMPTY_CONE {
            -1.0
        } else {
            (f64::from(angle_units) / ANGLE_UNITS * std::f64::consts::PI) as f32
        };
        nodes[k as usize] = NodeRecord {
            parent: U32::new(parent),
            first_child: U32::new(first_child),
            child_count,
            flags: if two_sided { FLAG_TWO_SIDED_CONE } else { 0 },
            depth: U16::new(depth),
            leaf_begin: U32::new(leaf_begin),
            leaf_end: U32::new(leaf_end as u32),
            subtri_begin: U32::new(subtri_index),
            subtri_count: U32::new(subtri_count),
            proxy: proxy.map(f),
            error_radius: f(error_radius),
            surface_error: f(surface_error),
            sphere: [
                centre[0],
                centre[1],
                centre[2],
                radius_units as f32 * grid.step,
            ]
            .map(f),
            cone: [axis[0], axis[1], axis[2], half].map(f),
        };
    }
    if subtri_begin != u64::from(first_triangle) + u64::from(triangle_count) {
        return Err("subtri counts do not add up to the page's triangles".into());
    }
    triangles.resize(triangle_count as usize, TriangleRecord::new_zeroed());
    let mut next_triangle = 0;
    let [.., corners_stream, parts] = &mut streams[..] else {
        unreachable!()
    };
    let mut previous_part = 0i64;
    for n in nodes.iter() {
        let begin = i64::from(n.leaf_begin.get());
        for _ in 0..n.subtri_count.get() {
            let mut corners = [U32::new(0); 3];
            for c in &mut corners {
                // `begin` is below 2³², so a sum past `i64::MAX` wraps to a negative value,
                // which the unsigned comparison refuses like any other.
                let v = begin.wrapping_add(unzigzag(
                    corners_stream.varint().ok_or_else(|| bad("corner"))?,
                ));
                if v as u64 >= file_vertices {
                    return Err(bad("corner"));
                }
                *c = U32::new(v as u32);
            }
            // As for corners: the previous part is a valid index, far below 2⁶³, so a sum
            // that wraps is negative and refused.
            let part =
                previous_part.wrapping_add(unzigzag(parts.varint().ok_or_else(|| bad("part"))?));
            if part as u64 >= part_count.max(1) {
                return Err(bad("part"));
            }
            previous_part = part;
            // In range: the subtri counts add up to the triangle count (checked above).
            triangles[next_triangle] = TriangleRecord {
                corners,
                part: U32::new(part as u32),
            };
            next_triangle += 1;
        }
    }
    if !streams.iter().all(Stream::done) {
        return Err("streams hold more than the page's records".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_steps_round_trip_and_keep_small_steps_small() {
        for value in 0..=255u8 {
            for predicted in 0..=255u8 {
                let step = byte_step(value, predicted);
                assert_eq!(unbyte_step(step, predicted), value);
                let distance = value
                    .wrapping_sub(predicted)
                    .min(predicted.wrapping_sub(value));
                assert!(
                    u16::from(step) <= 2 * u16::from(distance),
                    "{value} {predicted}"
                );
            }
        }
    }

    #[test]
    fn varints_and_zigzag_round_trip() {
        for v in [0i64, 1, -1, 63, -64, 1 << 40, i64::MIN / 2, i64::MAX / 2] {
            let mut out = Vec::new();
            put_varint(&mut out, zigzag(v));
            let mut s = Stream { bytes: &out, at: 0 };
            assert_eq!(unzigzag(s.varint().unwrap()), v);
            assert!(s.done());
        }
    }

    #[test]
    fn a_leaf_with_subtris_is_refused() {
        use zerocopy::FromZeros;
        let grid = Grid {
            origin: [0.0; 3],
            step: 1.0,
        };
        let mut leaf = NodeRecord::new_zeroed();
        leaf.parent = U32::new(NO_NODE);
        leaf.first_child = U32::new(NO_NODE);
        leaf.leaf_end = U32::new(1);
        assert!(encode_page(&grid, 0, &[leaf], &[]).is_ok());
        leaf.subtri_count = U32::new(1);
        let triangle = TriangleRecord::new_zeroed();
        assert!(encode_page(&grid, 0, &[leaf], &[triangle]).is_err());
    }

    fn node(parent: u32, depth: u16, leaves: std::ops::Range<u32>, x: f32) -> NodeRecord {
        use zerocopy::FromZeros;
        let mut n = NodeRecord::new_zeroed();
        n.parent = U32::new(parent);
        n.first_child = U32::new(NO_NODE);
        n.depth = U16::new(depth);
        n.leaf_begin = U32::new(leaves.start);
        n.leaf_end = U32::new(leaves.end);
        n.proxy = [x, 0.0, 0.0].map(F32::new);
        n
    }

    fn inner(mut n: NodeRecord, children: std::ops::Range<u32>, subtris: u32) -> NodeRecord {
        n.first_child = U32::new(children.start);
        n.child_count = (children.end - children.start) as u8;
        n.subtri_count = U32::new(subtris);
        n.error_radius = F32::new(2.0);
        n.surface_error = F32::new(0.5);
        n.sphere = [1.0, 0.0, 0.0, 2.0].map(F32::new);
        n.cone = [0.0, 0.0, 1.0, 0.1].map(F32::new);
        n
    }

    /// Two pages of one small tree: the root's page (root; leaf 1; inner node 2 over leaf
    /// ranks 1..3 with one subtri; its leaves 3 and 4), and a page of two nodes whose
    /// parents lie outside it, so each spells out its depth and first leaf.
    fn pages() -> (Grid, [(Vec<u8>, PageShape); 2]) {
        let grid = Grid {
            origin: [0.0; 3],
            step: 1.0,
        };
        let shape = |first_node, node_count, triangle_count| PageShape {
            first_node,
            node_count,
            first_triangle: 0,
            triangle_count,
            file_nodes: 5,
            file_vertices: 3,
            max_depth: 2,
            parts: 2,
        };
        let triangle = |corners: [u32; 3], part| TriangleRecord {
            corners: corners.map(U32::new),
            part: U32::new(part),
        };
        let mut c = inner(node(0, 1, 1..3, 1.0), 3..5, 1);
        c.subtri_begin = U32::new(1);
        let root_page = [
            inner(node(NO_NODE, 0, 0..3, 1.0), 1..3, 1),
            node(0, 1, 0..1, 0.0),
            c,
            node(2, 2, 1..2, 1.0),
            node(2, 2, 2..3, 2.0),
        ];
        let triangles = [triangle([0, 1, 2], 1), triangle([1, 2, 0], 1)];
        let first = encode_page(&grid, 0, &root_page, &triangles).unwrap();
        let other = [node(1, 2, 1..2, 1.0), node(2, 2, 2..3, 2.0)];
        let second = encode_page(&grid, 3, &other, &[]).unwrap();
        (grid, [(first, shape(0, 5, 2)), (second, shape(3, 2, 0))])
    }

    /// `raw` with value `n` of stream `k` replaced by `value`.
    fn with_value(raw: &[u8], k: usize, n: usize, value: u64) -> Vec<u8> {
        let length = |j: usize| u32::from_le_bytes(raw[4 * j..4 * j + 4].try_into().unwrap());
        let mut streams: Vec<Vec<u8>> = Vec::new();
        let mut at = 4 * STREAMS;
        for j in 0..STREAMS {
            let end = at + length(j) as usize;
            streams.push(raw[at..end].to_vec());
            at = end;
        }
        let mut reader = Stream {
            bytes: &streams[k],
            at: 0,
        };
        for _ in 0..n {
            reader.varint().unwrap();
        }
        let start = reader.at;
        reader.varint().unwrap();
        let mut replaced = streams[k][..start].to_vec();
        put_varint(&mut replaced, value);
        replaced.extend_from_slice(&streams[k][reader.at..]);
        streams[k] = replaced;
        let mut out = Vec::new();
        for stream in &streams {
            out.extend_from_slice(&(stream.len() as u32).to_le_bytes());
        }
        for stream in &streams {
            out.extend_from_slice(stream);
        }
        out
    }

    /// Steps that would overflow 64-bit arithmetic where they are added to a non-zero base
    /// (a previous node's depth or leaf end, an inner node's first leaf, the previous part)
    /// are errors, in debug builds as in release ones.
    #[test]
    fn huge_steps_in_hostile_streams_are_errors_not_overflows() {
        let (grid, [(first, first_shape), (second, second_shape)]) = pages();
        let decode = |raw: &[u8], shape: &PageShape| {
            let (mut nodes, mut triangles) = (Vec::new(), Vec::new());
            decode_page(
                &grid,
                raw,
                shape,
                &mut Scratch::default(),
                &mut nodes,
                &mut triangles,
            )
        };
        decode(&first, &first_shape).expect("the root page as written decodes");
        decode(&second, &second_shape).expect("the other page as written decodes");
        // (page, stream, value index): the second node's depth and first leaf; the inner
        // node's leaf count and first corner; the second triangle's part.
        let cases = [
            (1, DEPTH, 1),
            (1, LEAF_BEGIN, 1),
            (0, LEAF_COUNT, 1),
            (0, CORNERS, 3),
            (0, PART, 1),
        ];
        for (page, stream, n) in cases {
            let (raw, shape) = [(&first, &first_shape), (&second, &second_shape)][page];
            for value in [u64::MAX, u64::MAX - 1, 1 << 63, (1 << 63) - 1] {
                assert!(
                    decode(&with_value(raw, stream, n, value), shape).is_err(),
                    "stream {stream}, value {value}"
                );
            }
        }
    }

    /// A decoded surface error bounds the written one plus the proxy's move, and stays
    /// within the decoded error radius; the page's inner nodes come back so.
    #[test]
    fn surface_errors_decode_conservatively() {
        for (surface, moved, radius) in [
            (0.0f32, 0.0, 1.0),
            (0.0, 0.01, 1.0),
            (0.3, 0.0, 1.0),
            (0.3, 0.02, 1.0),
            (0.999, 0.001, 1.0),
            (1.5, 0.0, 1.0),
            (f32::NAN, 0.0, 1.0),
        ] {
            let byte = surface_byte(surface, moved, radius);
            let decoded = radius * surface_share(byte);
            assert!(byte <= SURFACE_LEVELS && decoded <= radius);
            if surface.is_finite() {
                let wanted = (f64::from(surface) + moved).min(radius);
                assert!(decoded >= wanted, "{surface} {moved}: {decoded}");
                // Half an octave above at most, or the smallest level.
                assert!(
                    decoded <= (wanted * std::f64::consts::SQRT_2).max(surface_share(1)) + 1e-12,
                    "{surface} {moved}: {decoded}"
                );
            } else {
                assert_eq!(byte, SURFACE_LEVELS);
            }
        }
        for u in 1..=SURFACE_LEVELS {
            assert!(surface_share(u - 1) < surface_share(u));
        }
        assert_eq!(surface_share(SURFACE_LEVELS), 1.0);
        let (grid, [(first, shape), _]) = pages();
        let (mut nodes, mut triangles) = (Vec::new(), Vec::new());
        decode_page(
            &grid,
            &first,
            &shape,
            &mut Scratch::default(),
            &mut nodes,
            &mut triangles,
        )
        .unwrap();
        for n in nodes.iter().filter(|n| n.child_count > 0) {
            assert!(n.surface_error.get() >= 0.0);
            assert!(n.surface_error.get() <= n.error_radius.get());
        }
    }

    #[test]
    fn octahedral_axes_are_close() {
        for axis in [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [0.6, -0.8, 0.0],
            [0.577, 0.577, -0.577],
        ] {
            let n = (axis.iter().map(|c: &f32| c * c).sum::<f32>()).sqrt();
            let axis = axis.map(|c| c / n);
            // One byte per coordinate: within about a degree; the encoder widens cones by the
            // actual error.
            assert!(angle(axis, unoctahedral(octahedral(axis))) < 0.02);
        }
    }
}
