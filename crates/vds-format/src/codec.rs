//! The page encoding of version 2: nodes and triangles as columns of small integers
//! (LEB128 varints, zig-zag for signed deltas), each column in its own stream so zstd sees
//! similar bytes together. Positions are grid coordinates delta-coded against the previous
//! node; leaf ids are coded relative to the owning node's leaf range; leaves carry no bounds
//! (a leaf never unfolds, so no runtime test reads them).
//!
//! Encoding widens bounds for what it quantises (proxy, sphere centre, cone axis), so decoded
//! bounds stay conservative. Decoding checks every length and value; it never reads past a
//! stream or trusts a count it has not bounded.

use zerocopy::little_endian::{F32, U16, U32};

use crate::VdtError;
use crate::grid::Grid;
use crate::layout::{NO_NODE, NodeRecord, TriangleRecord};

/// The streams of a page, in order.
const STREAMS: usize = 12;

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

/// Octahedral encoding of a unit vector in two 16-bit numbers.
fn octahedral(axis: [f32; 3]) -> [u16; 2] {
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
    [u, v].map(|c| (((c.clamp(-1.0, 1.0) + 1.0) * 0.5 * 65535.0).round()) as u16)
}

fn unoctahedral(e: [u16; 2]) -> [f32; 3] {
    let [u, v] = e.map(|c| f64::from(c) / 65535.0 * 2.0 - 1.0);
    let z = 1.0 - u.abs() - v.abs();
    let (x, y) = if z < 0.0 {
        ((1.0 - v.abs()) * u.signum(), (1.0 - u.abs()) * v.signum())
    } else {
        (u, v)
    };
    let n = (x * x + y * y + z * z).sqrt();
    [x / n, y / n, z / n].map(|c| c as f32)
}

fn angle(a: [f32; 3], b: [f32; 3]) -> f64 {
    let [a, b] = [a, b].map(|v| v.map(f64::from));
    let c = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let sin = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    sin.atan2(a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
}

/// Half-angles are stored in units of π / 65534, rounded up; 65535 marks the empty cone.
const ANGLE_UNITS: f64 = 65534.0;
const EMPTY_CONE: u16 = u16::MAX;

fn distance(a: [f32; 3], b: [f32; 3]) -> f64 {
    (0..3)
        .map(|k| (f64::from(a[k]) - f64::from(b[k])).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Encodes one page: `nodes` with ids from `first_node`, and their subtris `triangles`.
/// Leaf positions must lie on the grid.
pub fn encode_page(
    grid: &Grid,
    first_node: u32,
    nodes: &[NodeRecord],
    triangles: &[TriangleRecord],
) -> Result<Vec<u8>, VdtError> {
    let mut s: [Vec<u8>; STREAMS] = Default::default();
    let (mut previous_leaf, mut previous_q) = (0i64, [0i64; 3]);
    for (k, n) in nodes.iter().enumerate() {
        let id = first_node + k as u32;
        let proxy = n.proxy.map(|c| c.get());
        let q = grid.quantize(proxy);
        s[0].push(n.child_count);
        put_varint(
            &mut s[1],
            if n.parent.get() == NO_NODE {
                0
            } else {
                u64::from(id - n.parent.get())
            },
        );
        put_varint(&mut s[3], u64::from(n.depth.get()));
        put_varint(
            &mut s[4],
            zigzag(i64::from(n.leaf_begin.get()) - previous_leaf),
        );
        previous_leaf = i64::from(n.leaf_begin.get());
        put_varint(&mut s[6], u64::from(n.subtri_count.get()));
        for a in 0..3 {
            put_varint(&mut s[7], zigzag(i64::from(q[a]) - previous_q[a]));
            previous_q[a] = i64::from(q[a]);
        }
        let stored = grid.dequantize(q);
        if n.child_count == 0 {
            if stored != proxy {
                return Err(VdtError::invalid(
                    format!("node {id}"),
                    "leaf position is not on the file's grid",
                ));
            }
            continue;
        }
        put_varint(&mut s[2], u64::from(n.first_child.get() - id));
        put_varint(&mut s[5], u64::from(n.leaf_end.get() - n.leaf_begin.get()));
        // Bounds, widened by what quantising the proxy, centre and axis moved.
        let moved = distance(proxy, stored);
        put_varint(
            &mut s[8],
            u64::from(grid.units_up(f64::from(n.error_radius.get()) + moved)),
        );
        let centre = [n.sphere[0].get(), n.sphere[1].get(), n.sphere[2].get()];
        let centre_q = grid.quantize(centre);
        for a in 0..3 {
            put_varint(&mut s[8], zigzag(i64::from(centre_q[a]) - i64::from(q[a])));
        }
        let centre_moved = distance(centre, grid.dequantize(centre_q));
        put_varint(
            &mut s[8],
            u64::from(grid.units_up(f64::from(n.sphere[3].get()) + centre_moved)),
        );
        let axis = [n.cone[0].get(), n.cone[1].get(), n.cone[2].get()];
        let half_angle = f64::from(n.cone[3].get());
        let (encoded, units) = if half_angle < 0.0 {
            ([0u16; 2], EMPTY_CONE)
        } else {
            let e = octahedral(axis);
            let widened = half_angle + angle(axis, unoctahedral(e));
            let units = (widened / std::f64::consts::PI * ANGLE_UNITS).ceil() + 1.0;
            (e, units.min(ANGLE_UNITS) as u16)
        };
        s[9].extend_from_slice(&encoded[0].to_le_bytes());
        s[9].extend_from_slice(&encoded[1].to_le_bytes());
        s[9].extend_from_slice(&units.to_le_bytes());
    }
    // Triangles: corners relative to the owning node's first leaf, parts as deltas.
    let mut t = 0usize;
    let mut previous_part = 0i64;
    for n in nodes {
        let begin = i64::from(n.leaf_begin.get());
        for tri in &triangles[t..t + n.subtri_count.get() as usize] {
            for c in tri.corners {
                put_varint(&mut s[10], zigzag(i64::from(c.get()) - begin));
            }
            put_varint(
                &mut s[11],
                zigzag(i64::from(tri.part.get()) - previous_part),
            );
            previous_part = i64::from(tri.part.get());
        }
        t += n.subtri_count.get() as usize;
    }
    let mut out = Vec::with_capacity(4 * STREAMS + s.iter().map(Vec::len).sum::<usize>());
    for stream in &s {
        out.extend_from_slice(&(stream.len() as u32).to_le_bytes());
    }
    for stream in &s {
        out.extend_from_slice(stream);
    }
    Ok(out)
}

/// A bounds-checked reader of one stream.
struct Stream<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Stream<'_> {
    fn varint(&mut self) -> Option<u64> {
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

    fn byte(&mut self) -> Option<u8> {
        let b = *self.bytes.get(self.at)?;
        self.at += 1;
        Some(b)
    }

    fn u16(&mut self) -> Option<u16> {
        Some(u16::from_le_bytes([self.byte()?, self.byte()?]))
    }

    fn done(&self) -> bool {
        self.at == self.bytes.len()
    }
}

/// Decodes a page encoded by [`encode_page`]. Structural checks of the decoded records are
/// the caller's; this checks the encoding itself (lengths, ranges, no trailing bytes).
pub fn decode_page(
    grid: &Grid,
    raw: &[u8],
    first_node: u32,
    node_count: u32,
    triangle_count: u32,
    first_triangle: u32,
) -> Result<(Vec<NodeRecord>, Vec<TriangleRecord>), String> {
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
    let mut nodes = Vec::with_capacity(node_count as usize);
    let (mut previous_leaf, mut previous_q) = (0i64, [0i64; 3]);
    let mut subtri_begin = u64::from(first_triangle);
    for k in 0..node_count {
        let id = first_node + k;
        let [s0, s1, s2, s3, s4, s5, s6, s7, s8, s9, ..] = &mut streams[..] else {
            unreachable!()
        };
        let child_count = s0.byte().ok_or_else(|| bad("child count"))?;
        let parent_delta = s1.varint().ok_or_else(|| bad("parent"))?;
        let parent = if parent_delta == 0 {
            NO_NODE
        } else {
            u32::try_from(
                u64::from(id)
                    .checked_sub(parent_delta)
                    .ok_or_else(|| bad("parent"))?,
            )
            .map_err(|_| bad("parent"))?
        };
        let depth =
            u16::try_from(s3.varint().ok_or_else(|| bad("depth"))?).map_err(|_| bad("depth"))?;
        let leaf_begin = previous_leaf
            .checked_add(unzigzag(s4.varint().ok_or_else(|| bad("leaf"))?))
            .ok_or_else(|| bad("leaf"))?;
        previous_leaf = leaf_begin;
        let leaf_begin = u32::try_from(leaf_begin).map_err(|_| bad("leaf"))?;
        let subtri_count = u32::try_from(s6.varint().ok_or_else(|| bad("subtris"))?)
            .map_err(|_| bad("subtris"))?;
        let mut q = [0u32; 3];
        for a in 0..3 {
            let v = previous_q[a]
                .checked_add(unzigzag(s7.varint().ok_or_else(|| bad("position"))?))
                .ok_or_else(|| bad("position"))?;
            previous_q[a] = v;
            q[a] = u32::try_from(v)
                .ok()
                .filter(|&c| c <= crate::grid::GRID_STEPS)
                .ok_or_else(|| bad("position"))?;
        }
        let proxy = grid.dequantize(q);
        let mut node = NodeRecord {
            parent: U32::new(parent),
            first_child: U32::new(NO_NODE),
            child_count,
            reserved: 0,
            depth: U16::new(depth),
            leaf_begin: U32::new(leaf_begin),
            leaf_end: U32::new(leaf_begin.checked_add(1).ok_or_else(|| bad("leaf"))?),
            subtri_begin: U32::new(u32::try_from(subtri_begin).map_err(|_| bad("subtris"))?),
            subtri_count: U32::new(subtri_count),
            proxy: proxy.map(f),
            error_radius: f(0.0),
            sphere: [proxy[0], proxy[1], proxy[2], 0.0].map(f),
            cone: [0.0, 0.0, 1.0, -1.0].map(f),
        };
        subtri_begin += u64::from(subtri_count);
        if child_count > 0 {
            let first_child = u64::from(id) + s2.varint().ok_or_else(|| bad("children"))?;
            node.first_child = U32::new(u32::try_from(first_child).map_err(|_| bad("children"))?);
            let count = s5.varint().ok_or_else(|| bad("leaf count"))?;
            let leaf_end = u64::from(leaf_begin) + count;
            node.leaf_end = U32::new(u32::try_from(leaf_end).map_err(|_| bad("leaf count"))?);
            let units = |s: &mut Stream| -> Result<f32, String> {
                Ok(s.varint()
                    .filter(|&u| u <= u64::from(u32::MAX))
                    .ok_or_else(|| bad("bound"))? as f32
                    * grid.step)
            };
            node.error_radius = f(units(s8)?);
            let mut centre_q = [0u32; 3];
            for a in 0..3 {
                let v = i64::from(q[a]) + unzigzag(s8.varint().ok_or_else(|| bad("sphere"))?);
                centre_q[a] = u32::try_from(v)
                    .ok()
                    .filter(|&c| c <= crate::grid::GRID_STEPS)
                    .ok_or_else(|| bad("sphere"))?;
            }
            let centre = grid.dequantize(centre_q);
            let radius = units(s8)?;
            node.sphere = [centre[0], centre[1], centre[2], radius].map(f);
            let e = [
                s9.u16().ok_or_else(|| bad("cone"))?,
                s9.u16().ok_or_else(|| bad("cone"))?,
            ];
            let angle_units = s9.u16().ok_or_else(|| bad("cone"))?;
            let axis = unoctahedral(e);
            let half = if angle_units == EMPTY_CONE {
                -1.0
            } else {
                (f64::from(angle_units) / ANGLE_UNITS * std::f64::consts::PI) as f32
            };
            node.cone = [axis[0], axis[1], axis[2], half].map(f);
        }
        nodes.push(node);
    }
    if subtri_begin != u64::from(first_triangle) + u64::from(triangle_count) {
        return Err("subtri counts do not add up to the page's triangles".into());
    }
    let mut triangles = Vec::with_capacity(triangle_count as usize);
    let [.., s10, s11] = &mut streams[..] else {
        unreachable!()
    };
    let mut previous_part = 0i64;
    for n in &nodes {
        let begin = i64::from(n.leaf_begin.get());
        for _ in 0..n.subtri_count.get() {
            let mut corners = [U32::new(0); 3];
            for c in &mut corners {
                let v = begin + unzigzag(s10.varint().ok_or_else(|| bad("corner"))?);
                *c = U32::new(u32::try_from(v).map_err(|_| bad("corner"))?);
            }
            let part = previous_part + unzigzag(s11.varint().ok_or_else(|| bad("part"))?);
            previous_part = part;
            triangles.push(TriangleRecord {
                corners,
                part: U32::new(u32::try_from(part).map_err(|_| bad("part"))?),
            });
        }
    }
    if !streams.iter().all(Stream::done) {
        return Err("streams hold more than the page's records".into());
    }
    Ok((nodes, triangles))
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn octahedral_axes_are_close() {
        for axis in [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [0.6, -0.8, 0.0],
            [0.577, 0.577, -0.577],
        ] {
            let n = (axis.iter().map(|c: &f32| c * c).sum::<f32>()).sqrt();
            let axis = axis.map(|c| c / n);
            assert!(angle(axis, unoctahedral(octahedral(axis))) < 1e-3);
        }
    }
}
