//! A shard's part (`.vdtpart`): what the merge needs of each of its roots and its corners of
//! triangles across roots. The file's layout is the sharded build's container
//! ([`super::container`]); its body is:
//!
//! - the root count (`u32`);
//! - per root: its index, top node count, top triangle count, region count and leaf count
//!   (`u32` each), its accumulated sums and sphere ([`SUMS_BYTES`] bytes: the quadric's 10,
//!   the position sum's 3 `f64`, the vertex and triangle boxes' 12 `f32`, the one-sided
//!   cone's axis and angle as 4 `f64`, a byte saying whether a two-sided cone follows and its
//!   4 `f64`, the sphere's 4 `f32`), its top nodes' subtree ids (`u32`), node records and
//!   triangle records (the `.vdt` record layouts), its leaves' positions (3 `f32` each), and
//!   its regions in leaf order: each its root's subtree id and page count (`u32`), its pages,
//!   each a kind byte and
//!   - 0, *sealed*: its frame length, decoded length, node count and triangle count (`u32`
//!     each) and the frame;
//!   - 1, *open*: its first node's region-relative id, node count and triangle count (`u32`
//!     each), its nodes' subtree ids (`u32`), node records and triangle records;
//!
//!   then the region's nodes by child count (9 `u64`), the deepest depth (`u32`), and its
//!   triangles per part (a count, `u32`, then part `u32` and triangles `u64` each);
//! - the cross-corner count (`u64`) and the cross corners, 25 bytes each (triangle `u64`,
//!   corner `u8`, root, rank, part and owner `u32`).
//!
//! Records hold the file's depths and leaf ranks and link by subtree ids (see
//! [`super::RootPart`]); an open page's link to a region node is its region-relative id. A
//! sealed page is the file's (`vds_format::encode_detached_region`); the merge copies it
//! without decoding it, so a part made by hand can make a wrong file but never a panic: the
//! `.vdt` reader checks every page.
//!
//! The reader checks every count against the body, every range a record holds against the
//! plan and the root, and that every value is finite, before the merge uses it; the merge
//! checks the links as it walks them. The merge's first pass reads only each root's head and
//! top, its regions' and pages' heads and the cross corners ([`read_part_head`]), checked
//! alike, and seeks over the rest: the body's checksum is verified by the second, whole read.

use std::path::Path;

use vds_format::{NO_NODE, NodeRecord, TriangleRecord};
use zerocopy::IntoBytes;

use super::container::{
    BodyReader, BodyWriter, Codec, Durability, HEADER_BYTES, TRAILER_BYTES, Trailer, body_stream,
    file_size, parse_header, parse_trailer, read_ends,
};
use super::merge::{PartHead, PartRead, RootHead, ShardHead};
use super::part::{CrossCorner, OpenPage, RegionPage, RegionPart, RootPart, ShardInput, ShardPart};
use super::{Plan, ShardError};
use crate::bounds::{Aabb, NormalCone};
use crate::build::{Accumulator, Sphere};
use crate::quadric::Quadric;

/// The first eight bytes of a `.vdtpart` file.
pub const PART_MAGIC: [u8; 8] = *b"VDTPART\0";
/// What errors call the file.
const WHAT: &str = ".vdtpart file";
/// Bytes of a root's sums and sphere in the body.
const SUMS_BYTES: usize = 10 * 8 + 3 * 8 + 12 * 4 + 4 * 8 + 1 + 4 * 8 + 4 * 4;
const CROSS_BYTES: usize = 8 + 1 + 4 * 4;
/// Kind bytes of a region.
const SEALED: u8 = 0;
const OPEN: u8 = 1;
/// Bytes of a page's head: its kind, and four lengths or counts.
const PAGE_HEAD_BYTES: u64 = 17;
const REGION_TAIL_BYTES: u64 = 9 * 8 + 4 + 4;
const NODE_BYTES: usize = vds_format::layout::NODE_BYTES;
const TRIANGLE_BYTES: usize = vds_format::layout::TRIANGLE_BYTES;

/// Writes `part` to `path` (a temporary file, synced, then renamed).
pub fn write_part(path: &Path, part: &ShardPart) -> Result<(), ShardError> {
    let mut out = BodyWriter::create(
        path,
        PART_MAGIC,
        part.index,
        part.plan_id,
        Durability::Synced,
    )?;
    out.put(&(part.roots.len() as u32).to_le_bytes())?;
    for root in &part.roots {
        put_root(&mut out, root)?;
    }
    put_cross(&mut out, &part.cross)?;
    out.finish()
}

/// Builds shard `index` of `plan` from its input and writes its part to `path`, each root as
/// soon as it is built: what [`super::build_shard_from`] and [`write_part`] do, without
/// holding every root's records at once; `durability`: whether the file is synced before it
/// is renamed into place. Returns the number of cross-root corners.
pub fn write_shard(
    path: &Path,
    plan: &Plan,
    index: u32,
    input: ShardInput,
    durability: Durability,
) -> Result<usize, ShardError> {
    plan.check_index(index)?;
    let mut out = BodyWriter::create(path, PART_MAGIC, index, plan.id, durability)?;
    out.put(&(plan.shard_roots(index).len() as u32).to_le_bytes())?;
    let cross = super::build_shard_into(plan, index, input, |root| put_root(&mut out, &root))?;
    put_cross(&mut out, &cross)?;
    out.finish()?;
    Ok(cross.len())
}

/// One root's entry of a part's body.
fn put_root(out: &mut BodyWriter, root: &RootPart) -> Result<(), ShardError> {
    let mut head = Vec::with_capacity(20 + SUMS_BYTES);
    for n in [
        root.root,
        root.top_ids.len() as u32,
        root.top_triangles.len() as u32,
        root.regions.len() as u32,
        root.leaves.len() as u32,
    ] {
        head.extend_from_slice(&n.to_le_bytes());
    }
    put_sums(&mut head, &root.sums, &root.sphere);
    out.put(&head)?;
    out.put(root.top_ids.as_bytes())?;
    out.put(root.top_nodes.as_bytes())?;
    out.put(root.top_triangles.as_bytes())?;
    out.put(root.leaves.as_bytes())?;
    for region in &root.regions {
        let mut head = Vec::new();
        head.extend_from_slice(&region.root.to_le_bytes());
        head.extend_from_slice(&(region.pages.len() as u32).to_le_bytes());
        out.put(&head)?;
        for page in &region.pages {
            match page {
                RegionPage::Sealed(page) => {
                    let mut head = vec![SEALED];
                    for n in [
                        page.frame.len() as u32,
                        page.raw_length,
                        page.node_count,
                        page.triangle_count,
                    ] {
                        head.extend_from_slice(&n.to_le_bytes());
                    }
                    out.put(&head)?;
                    out.put(&page.frame)?;
                }
                RegionPage::Open(page) => {
                    let mut head = vec![OPEN];
                    for n in [
                        page.first,
                        page.ids.len() as u32,
                        page.triangles.len() as u32,
                    ] {
                        head.extend_from_slice(&n.to_le_bytes());
                    }
                    out.put(&head)?;
                    out.put(page.ids.as_bytes())?;
                    out.put(page.nodes.as_bytes())?;
                    out.put(page.triangles.as_bytes())?;
                }
            }
        }
        let mut tail = Vec::new();
        tail.extend_from_slice(region.degree_histogram.as_bytes());
        tail.extend_from_slice(&region.max_depth.to_le_bytes());
        tail.extend_from_slice(&(region.part_triangles.len() as u32).to_le_bytes());
        for (part, count) in &region.part_triangles {
            tail.extend_from_slice(&part.to_le_bytes());
            tail.extend_from_slice(&count.to_le_bytes());
        }
        out.put(&tail)?;
    }
    Ok(())
}

/// The cross-root corners at the end of a part's body.
fn put_cross(out: &mut BodyWriter, cross: &[CrossCorner]) -> Result<(), ShardError> {
    out.put(&(cross.len() as u64).to_le_bytes())?;
    let mut record = Vec::with_capacity(CROSS_BYTES);
    for c in cross {
        record.clear();
        record.extend_from_slice(&c.triangle.to_le_bytes());
        record.push(c.corner);
        for n in [c.root, c.rank, c.part, c.owner] {
            record.extend_from_slice(&n.to_le_bytes());
        }
        out.put(&record)?;
    }
    Ok(())
}

/// The most body bytes shard `index` of `plan` can hold: a subtree has fewer than twice its
/// vertices in nodes, each stored once (a record with its id, or in a page, its encoding
/// shorter than its record, with a region's lengths and counts), a position per vertex, and
/// each of the shard's input triangles stored once (a record, or in a page with its part
/// counted) or has at most three corners reported.
fn body_limit(plan: &Plan, index: u32) -> u64 {
    let roots = plan.shard_roots(index);
    let vertices: u64 = roots
        .clone()
        .map(|r| {
            let n = plan.root_node(r);
            u64::from(n.leaf_end - n.leaf_begin)
        })
        .sum();
    let triangles = plan.triangles_of_shard(index);
    let per_node = NODE_BYTES as u64 + 4 + PAGE_HEAD_BYTES + REGION_TAIL_BYTES + 5;
    12 + roots.len() as u64 * (20 + SUMS_BYTES as u64)
        + 2 * vertices * per_node
        + 12 * vertices
        + triangles * (TRIANGLE_BYTES as u64 + 12).max(3 * CROSS_BYTES as u64)
}

/// Which shard of which plan a part file is (its index and the plan's id), from its header
/// and trailer alone: a merge checks the set of parts before it reads any.
pub fn part_header(path: &Path) -> Result<(u32, u64), ShardError> {
    read_ends(path, PART_MAGIC, WHAT).map(|(h, _)| (h.index, h.plan_id))
}

/// Reads part file `path`, which must be a shard of `plan`, and checks every index it holds.
/// The body is decoded straight into the part's arrays, never held whole.
pub fn read_part(path: &Path, plan: &Plan) -> Result<ShardPart, ShardError> {
    read_part_checked(path, plan).map(PartRead::into_part)
}

/// [`read_part`], with the file's body checksum (verified): what [`super::merge_to`] compares
/// between its two reads of a part.
pub fn read_part_checked(path: &Path, plan: &Plan) -> Result<PartRead, ShardError> {
    let bad = |reason: String| ShardError::BadFile {
        path: path.to_path_buf(),
        reason,
    };
    let (header, trailer) = read_ends(path, PART_MAGIC, WHAT)?;
    check_stated(plan, header.plan_id, header.index, &trailer).map_err(bad)?;
    // A body is stored raw: the file holds exactly the body its trailer states (which
    // `check_stated` bounded by the shard's largest body), or it is refused before it is read.
    debug_assert_eq!(Codec::of(PART_MAGIC), Codec::Raw);
    let size = file_size(path)?;
    if size != HEADER_BYTES + TRAILER_BYTES + trailer.body_bytes {
        return Err(bad(format!(
            "{size} bytes, not the {} its trailer states",
            HEADER_BYTES + TRAILER_BYTES + trailer.body_bytes
        )));
    }
    let mut body = BodyReader::new(body_stream(path)?, Codec::of(PART_MAGIC), &trailer);
    let part = parse_body(&mut body, plan, header.index).map_err(bad)?;
    body.finish().map_err(bad)?;
    Ok(PartRead::from_file(part, trailer.body_checksum))
}

/// What the merge's first pass takes of part file `path`, which must be a shard of `plan`
/// ([`PartHead`]): its roots' heads and tops and its cross corners, checked as
/// [`read_part`] checks them, read while the leaves and pages are skipped (the file is
/// seeked over them, so its body checksum is not verified: the head carries the checksum its
/// trailer states, which the merge's full read of the part, which verifies it, must match).
pub fn read_part_head(path: &Path, plan: &Plan) -> Result<PartHead, ShardError> {
    let bad = |reason: String| ShardError::BadFile {
        path: path.to_path_buf(),
        reason,
    };
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    let (header, trailer) = read_ends(path, PART_MAGIC, WHAT)?;
    check_stated(plan, header.plan_id, header.index, &trailer).map_err(bad)?;
    let size = file_size(path)?;
    if size != HEADER_BYTES + TRAILER_BYTES + trailer.body_bytes {
        return Err(bad(format!(
            "{size} bytes, not the {} its trailer states",
            HEADER_BYTES + TRAILER_BYTES + trailer.body_bytes
        )));
    }
    let mut file = std::fs::File::open(path).map_err(io)?;
    std::io::Seek::seek(&mut file, std::io::SeekFrom::Start(HEADER_BYTES)).map_err(io)?;
    let mut body = BodyReader::skimming(file, &trailer);
    let head = skim_part(&mut body, plan, header.index).map_err(bad)?;
    Ok(PartHead::from_file(head, trailer.body_checksum))
}

/// [`read_part_head`] of the bytes of a `.vdtpart` file (for tests and fuzzing): the body is
/// read, not seeked over, but its checksum is not verified either.
pub fn part_head_from_bytes(data: &[u8], plan: &Plan) -> Result<PartHead, String> {
    let header = parse_header(data, PART_MAGIC, WHAT)?;
    let trailer = parse_trailer(data)?;
    check_stated(plan, header.plan_id, header.index, &trailer)?;
    let stored = &data[HEADER_BYTES as usize..data.len() - TRAILER_BYTES as usize];
    if stored.len() as u64 != trailer.body_bytes {
        return Err("a body of another length than its trailer states".into());
    }
    let mut body = BodyReader::new(stored, Codec::of(PART_MAGIC), &trailer);
    let head = skim_part(&mut body, plan, header.index)?;
    Ok(PartHead::from_file(head, trailer.body_checksum))
}

/// The skimmed part of shard `index` (its roots' heads and its cross corners), its body read
/// to the end.
fn skim_part(body: &mut BodyReader, plan: &Plan, index: u32) -> Result<ShardHead, String> {
    let roots = skim_body(body, plan, index)?;
    let leaves: Vec<u64> = roots.iter().map(|r| r.leaves).collect();
    let cross = parse_cross(body, plan, index, &leaves)?;
    if body.left() != 0 {
        return Err("bytes after the body".into());
    }
    Ok(ShardHead {
        plan_id: plan.id,
        index,
        roots,
        cross,
    })
}

/// The checks of a part's header and stated body length against the plan, before anything
/// is allocated for it.
fn check_stated(plan: &Plan, plan_id: u64, index: u32, trailer: &Trailer) -> Result<(), String> {
    if plan_id != plan.id {
        return Err(format!(
            "built for another plan (id {plan_id:016x}, this plan is {:016x})",
            plan.id
        ));
    }
    if index >= plan.shard_count() {
        return Err(format!(
            "shard {index} of a plan of {} shards",
            plan.shard_count()
        ));
    }
    let limit = body_limit(plan, index);
    if trailer.body_bytes > limit {
        return Err(format!(
            "states a body of {} bytes, more than its shard can hold ({limit})",
            trailer.body_bytes
        ));
    }
    Ok(())
}

/// A part from the bytes of a `.vdtpart` file, which must be a shard of `plan`; every index
/// it holds is checked. (What [`read_part`] does with a file.)
pub fn part_from_bytes(data: &[u8], plan: &Plan) -> Result<ShardPart, String> {
    let header = parse_header(data, PART_MAGIC, WHAT)?;
    let trailer = parse_trailer(data)?;
    check_stated(plan, header.plan_id, header.index, &trailer)?;
    let stored = &data[HEADER_BYTES as usize..data.len() - TRAILER_BYTES as usize];
    let mut body = BodyReader::new(stored, Codec::of(PART_MAGIC), &trailer);
    let part = parse_body(&mut body, plan, header.index)?;
    body.finish()?;
    Ok(part)
}

/// A cursor over the body that fails on reads past its end.
struct Cursor<'a> {
    bytes: &'a [u8],
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        if n > self.bytes.len() {
            return Err("truncated body".into());
        }
        let (head, tail) = self.bytes.split_at(n);
        self.bytes = tail;
        Ok(head)
    }
    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }
    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_bits(self.u32()?))
    }
    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn f32s<const N: usize>(&mut self) -> Result<[f32; N], String> {
        let mut out = [0.0; N];
        for x in &mut out {
            *x = self.f32()?;
        }
        Ok(out)
    }
    fn f64s<const N: usize>(&mut self) -> Result<[f64; N], String> {
        let mut out = [0.0; N];
        for x in &mut out {
            *x = self.f64()?;
        }
        Ok(out)
    }
}

fn put_sums(out: &mut Vec<u8>, sums: &Accumulator, sphere: &Sphere) {
    let mut f64s = |values: &[f64]| {
        for v in values {
            out.extend_from_slice(&v.to_le_bytes());
        }
    };
    f64s(&sums.quadric.a);
    f64s(&sums.quadric.b);
    f64s(&[sums.quadric.c]);
    f64s(&sums.position_sum);
    let f32s = |out: &mut Vec<u8>, values: &[f32]| {
        for v in values {
            out.extend_from_slice(&v.to_le_bytes());
        }
    };
    for b in [&sums.vertex_box, &sums.triangle_box] {
        f32s(out, &b.min);
        f32s(out, &b.max);
    }
    let cone = |out: &mut Vec<u8>, c: &NormalCone| {
        for v in c.axis.iter().chain([&c.half_angle]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    };
    cone(out, &sums.cone);
    out.push(u8::from(sums.two_sided.is_some()));
    cone(out, &sums.two_sided.unwrap_or(NormalCone::EMPTY));
    f32s(out, &sphere.center);
    f32s(out, &[sphere.radius]);
}

fn get_sums(c: &mut Cursor) -> Result<(Accumulator, Sphere), String> {
    let quadric = Quadric {
        a: c.f64s()?,
        b: c.f64s()?,
        c: c.f64()?,
    };
    let position_sum = c.f64s()?;
    let mut boxes = [Aabb::EMPTY; 2];
    for b in &mut boxes {
        b.min = c.f32s()?;
        b.max = c.f32s()?;
    }
    let cone = |c: &mut Cursor| -> Result<NormalCone, String> {
        Ok(NormalCone {
            axis: c.f64s()?,
            half_angle: c.f64()?,
        })
    };
    let one_sided = cone(c)?;
    let has_two_sided = c.u8()?;
    let two_sided = cone(c)?;
    let sums = Accumulator {
        quadric,
        position_sum,
        vertex_box: boxes[0],
        triangle_box: boxes[1],
        cone: one_sided,
        two_sided: match has_two_sided {
            0 => None,
            1 => Some(two_sided),
            _ => return Err("a flag byte that is neither 0 nor 1".into()),
        },
    };
    let sphere = Sphere {
        center: c.f32s()?,
        radius: c.f32()?,
    };
    // A root holds a vertex, so its boxes are not empty; every sum of finite inputs is finite.
    let finite = |xs: &[f64]| xs.iter().all(|x| x.is_finite());
    let boxes_hold = [&sums.vertex_box, &sums.triangle_box].iter().all(|b| {
        (0..3).all(|k| b.min[k].is_finite() && b.max[k].is_finite() && b.min[k] <= b.max[k])
    });
    let cones = [Some(sums.cone), sums.two_sided].into_iter().flatten();
    if !finite(&sums.quadric.a)
        || !finite(&sums.quadric.b)
        || !sums.quadric.c.is_finite()
        || !finite(&sums.position_sum)
        || !boxes_hold
        || !cones
            .into_iter()
            .all(|c| finite(&c.axis) && c.half_angle.is_finite())
        || !sphere.center.iter().all(|x| x.is_finite())
        || !(sphere.radius.is_finite() && sphere.radius >= 0.0)
    {
        return Err("a root's sums are not finite".into());
    }
    Ok((sums, sphere))
}

fn parse_body(body: &mut BodyReader, plan: &Plan, index: u32) -> Result<ShardPart, String> {
    let expected = expect_roots(body, plan, index)?;
    let mut roots = Vec::with_capacity(expected.len());
    for root in expected {
        let part = parse_root(body, plan, index, root).map_err(|e| format!("root {root}: {e}"))?;
        roots.push(part);
    }
    let leaves: Vec<u64> = roots.iter().map(|r| r.leaves.len() as u64).collect();
    let cross = parse_cross(body, plan, index, &leaves)?;
    Ok(ShardPart {
        plan_id: plan.id,
        index,
        roots,
        cross,
    })
}

/// [`parse_body`] skimming: what the merge's first pass takes of each root (its head, top and
/// regions' roots and triangle counts) and the cross corners, checked as a full read checks
/// them; leaves and pages are skipped.
fn skim_body(body: &mut BodyReader, plan: &Plan, index: u32) -> Result<Vec<RootHead>, String> {
    let expected = expect_roots(body, plan, index)?;
    let mut roots = Vec::with_capacity(expected.len());
    for root in expected {
        let head = skim_root(body, plan, index, root).map_err(|e| format!("root {root}: {e}"))?;
        roots.push(head);
    }
    Ok(roots)
}

/// The body's root count, checked against the plan's roots of shard `index`, which it returns.
fn expect_roots(
    body: &mut BodyReader,
    plan: &Plan,
    index: u32,
) -> Result<std::ops::Range<u32>, String> {
    let expected = plan.shard_roots(index);
    let root_count = u32::from_le_bytes(body.array()?);
    if root_count != expected.len() as u32 {
        return Err(format!(
            "{root_count} roots, the plan gives this shard {}",
            expected.len()
        ));
    }
    Ok(expected)
}

/// The cross corners at the end of the body of shard `index`, whose roots hold `leaves`
/// leaves each (in plan order).
fn parse_cross(
    body: &mut BodyReader,
    plan: &Plan,
    index: u32,
    leaves: &[u64],
) -> Result<Vec<CrossCorner>, String> {
    let first_root = plan.shard_roots(index).start;
    let cross_count = u64::from_le_bytes(body.array()?);
    if cross_count > body.left() / CROSS_BYTES as u64 {
        return Err("truncated body".into());
    }
    let mut cross = Vec::with_capacity(cross_count as usize);
    // Read in pieces of a few megabytes, then parsed.
    const PIECE: u64 = 1 << 16;
    let mut piece = Vec::new();
    let mut to_read = cross_count;
    while to_read > 0 {
        let n = to_read.min(PIECE);
        piece.resize(n as usize * CROSS_BYTES, 0);
        body.read_exact(&mut piece)?;
        to_read -= n;
        let mut c = Cursor { bytes: &piece };
        for _ in 0..n {
            let corner = CrossCorner {
                triangle: c.u64()?,
                corner: c.u8()?,
                root: c.u32()?,
                rank: c.u32()?,
                part: c.u32()?,
                owner: c.u32()?,
            };
            let &leaves = corner
                .root
                .checked_sub(first_root)
                .and_then(|k| leaves.get(k as usize))
                .ok_or_else(|| {
                    format!(
                        "a cross corner under root {}, not this shard's",
                        corner.root
                    )
                })?;
            if corner.triangle >= plan.triangles
                || corner.corner > 2
                || u64::from(corner.rank) >= leaves
                || (corner.owner != u32::MAX && u64::from(corner.owner) >= 2 * leaves)
            {
                return Err(format!(
                    "cross corner of triangle {} out of range",
                    corner.triangle
                ));
            }
            cross.push(corner);
        }
    }
    Ok(cross)
}

/// A root's entry up to its leaves: its head and top, and what the rest is checked against.
struct RootTop {
    /// The head, its regions' roots and triangles not filled in.
    head: RootHead,
    region_count: u32,
    leaf_count: u32,
    /// The root's leaf ranks, and the shard's (where a subtri's corners lie).
    ranks: std::ops::Range<u32>,
    corners: std::ops::Range<u32>,
    /// The most nodes the root's subtree can have.
    most_nodes: u64,
}

/// The entry of root `root` of shard `index` up to its leaves, checked.
fn parse_root_top(
    body: &mut BodyReader,
    plan: &Plan,
    index: u32,
    root: u32,
) -> Result<RootTop, String> {
    let head: [u8; 20] = body.array()?;
    let mut c = Cursor { bytes: &head };
    let (stated, top_count, top_triangle_count, region_count, leaf_count) =
        (c.u32()?, c.u32()?, c.u32()?, c.u32()?, c.u32()?);
    if stated != root {
        return Err(format!("root {stated} where the plan has root {root}"));
    }
    let node = plan.root_node(root);
    let ranks = node.leaf_begin..node.leaf_end;
    // A subtri's corners lie under the shard's roots (two under this one).
    let shard = plan.shard_roots(index);
    let corners = plan.root_node(shard.start).leaf_begin..plan.root_node(shard.end - 1).leaf_end;
    let most_nodes = 2 * u64::from(ranks.end - ranks.start);
    if leaf_count != ranks.end - ranks.start
        || top_count == 0
        || u64::from(top_count) > most_nodes
        || region_count > top_count
    {
        return Err(format!(
            "{top_count} top nodes, {region_count} regions and {leaf_count} leaves for {} vertices",
            ranks.end - ranks.start
        ));
    }
    let sums: [u8; SUMS_BYTES] = body.array()?;
    let (sums, sphere) = get_sums(&mut Cursor { bytes: &sums })?;
    let top_ids: Vec<u32> = body.records(top_count as usize)?;
    if top_ids[0] != 0 || top_ids.windows(2).any(|w| w[0] >= w[1]) {
        return Err("its top's ids are not ascending from its root".into());
    }
    let top_nodes: Vec<NodeRecord> = body.records(top_count as usize)?;
    let top_triangles: Vec<TriangleRecord> = body.records(top_triangle_count as usize)?;
    check_records(&top_nodes, &top_triangles, &ranks, &corners, most_nodes)
        .map_err(|e| format!("its top: {e}"))?;
    Ok(RootTop {
        head: RootHead {
            root,
            top_ids,
            top_nodes,
            top_triangles,
            sums,
            sphere,
            region_roots: Vec::new(),
            region_triangles: 0,
            leaves: u64::from(leaf_count),
        },
        region_count,
        leaf_count,
        ranks,
        corners,
        most_nodes,
    })
}

/// A region's head: its root's subtree id and its page count, checked against the body.
fn region_head(body: &mut BodyReader) -> Result<(u32, u32), String> {
    let head: [u8; 8] = body.array()?;
    let mut c = Cursor { bytes: &head };
    let (region_root, page_count) = (c.u32()?, c.u32()?);
    if page_count == 0 || u64::from(page_count) > body.left() / PAGE_HEAD_BYTES {
        return Err(format!("a region of {page_count} pages"));
    }
    Ok((region_root, page_count))
}

/// A page's head as a part states it.
enum PageHead {
    /// A page the shard encoded: its frame follows.
    Sealed {
        frame_length: u32,
        raw_length: u32,
        node_count: u32,
        triangle_count: u32,
    },
    /// A page's records: its nodes' subtree ids (the first in the head), nodes and triangles
    /// follow.
    Open {
        first: u32,
        first_id: u32,
        node_count: u32,
        triangle_count: u32,
    },
}

/// The next page's head, its nodes counted into `region_nodes`, which may not pass
/// `most_nodes`.
fn page_head(
    body: &mut BodyReader,
    region_nodes: &mut u64,
    most_nodes: u64,
) -> Result<PageHead, String> {
    let head: [u8; PAGE_HEAD_BYTES as usize] = body.array()?;
    let mut c = Cursor { bytes: &head };
    let kind = c.u8()?;
    let (a, b, d, e) = (c.u32()?, c.u32()?, c.u32()?, c.u32()?);
    match kind {
        SEALED => {
            let (frame_length, raw_length, node_count, triangle_count) = (a, b, d, e);
            *region_nodes += u64::from(node_count);
            if *region_nodes > most_nodes || raw_length > vds_format::MAX_PAGE_RAW_BYTES {
                return Err("a sealed page larger than its vertices can fill".into());
            }
            Ok(PageHead::Sealed {
                frame_length,
                raw_length,
                node_count,
                triangle_count,
            })
        }
        OPEN => {
            // The head's last `u32` is the first of the subtree ids.
            let (first, node_count, triangle_count, first_id) = (a, b, d, e);
            *region_nodes += u64::from(node_count);
            if node_count == 0 || *region_nodes > most_nodes {
                return Err(format!("an open page of {node_count} nodes"));
            }
            Ok(PageHead::Open {
                first,
                first_id,
                node_count,
                triangle_count,
            })
        }
        _ => Err(format!("a page of kind {kind}")),
    }
}

/// Root `root`'s entry skimmed (see [`skim_body`]): its head and top checked as
/// [`parse_root`] checks them, its regions' roots and page heads read, leaves and pages
/// skipped.
fn skim_root(
    body: &mut BodyReader,
    plan: &Plan,
    index: u32,
    root: u32,
) -> Result<RootHead, String> {
    let RootTop {
        mut head,
        region_count,
        leaf_count,
        most_nodes,
        ..
    } = parse_root_top(body, plan, index, root)?;
    body.skip(12 * u64::from(leaf_count))?;
    let mut region_nodes = 0u64;
    for _ in 0..region_count {
        let (region_root, page_count) = region_head(body)?;
        for _ in 0..page_count {
            let (skipped, triangle_count) = match page_head(body, &mut region_nodes, most_nodes)? {
                PageHead::Sealed {
                    frame_length,
                    triangle_count,
                    ..
                } => (u64::from(frame_length), triangle_count),
                PageHead::Open {
                    node_count,
                    triangle_count,
                    ..
                } => {
                    let records = (u64::from(node_count) - 1) * 4
                        + u64::from(node_count) * NODE_BYTES as u64
                        + u64::from(triangle_count) * TRIANGLE_BYTES as u64;
                    (records, triangle_count)
                }
            };
            body.skip(skipped)?;
            head.region_triangles += u64::from(triangle_count);
        }
        // The region's tail: its histogram and depth, then its triangles per part.
        body.skip(REGION_TAIL_BYTES - 4)?;
        let part_count = u32::from_le_bytes(body.array()?);
        body.skip(12 * u64::from(part_count))?;
        head.region_roots.push(region_root);
    }
    Ok(head)
}

/// One root's entry, checked: counts against the body and the root's vertices, ranges
/// against the root, values finite.
fn parse_root(
    body: &mut BodyReader,
    plan: &Plan,
    index: u32,
    root: u32,
) -> Result<RootPart, String> {
    let RootTop {
        head,
        region_count,
        leaf_count,
        ranks,
        corners,
        most_nodes,
    } = parse_root_top(body, plan, index, root)?;
    let RootHead {
        root,
        top_ids,
        top_nodes,
        top_triangles,
        sums,
        sphere,
        ..
    } = head;
    let leaves: Vec<[f32; 3]> = body.records(leaf_count as usize)?;
    if !leaves.iter().flatten().all(|x| x.is_finite()) {
        return Err("a leaf position that is not finite".into());
    }
    let mut regions = Vec::with_capacity(region_count as usize);
    let mut region_nodes = 0u64;
    for _ in 0..region_count {
        let (region_root, page_count) = region_head(body)?;
        let mut pages = Vec::with_capacity(page_count as usize);
        let (mut nodes_here, mut triangles_here) = (0u64, 0u64);
        for _ in 0..page_count {
            pages.push(match page_head(body, &mut region_nodes, most_nodes)? {
                PageHead::Sealed {
                    frame_length,
                    raw_length,
                    node_count,
                    triangle_count,
                } => RegionPage::Sealed(vds_format::EncodedPage {
                    frame: body.records(frame_length as usize)?,
                    raw_length,
                    node_count,
                    triangle_count,
                }),
                PageHead::Open {
                    first,
                    first_id,
                    node_count,
                    triangle_count,
                } => {
                    let mut ids = vec![first_id];
                    ids.extend(body.records::<u32>(node_count as usize - 1)?);
                    let nodes: Vec<NodeRecord> = body.records(node_count as usize)?;
                    let triangles: Vec<TriangleRecord> = body.records(triangle_count as usize)?;
                    check_records(&nodes, &triangles, &ranks, &corners, most_nodes + 1)
                        .map_err(|e| format!("an open page: {e}"))?;
                    RegionPage::Open(OpenPage {
                        first,
                        ids,
                        nodes,
                        triangles,
                    })
                }
            });
        }
        for page in &pages {
            nodes_here += page.node_count();
            triangles_here += page.triangle_count();
        }
        let tail: [u8; 9 * 8 + 4 + 4] = body.array()?;
        let mut c = Cursor { bytes: &tail };
        let mut degree_histogram = [0u64; 9];
        for d in &mut degree_histogram {
            *d = c.u64()?;
        }
        let max_depth = c.u32()?;
        let part_count = c.u32()?;
        if u64::from(part_count) > body.left() / 12 {
            return Err("truncated body".into());
        }
        let mut part_triangles = Vec::with_capacity(part_count as usize);
        for _ in 0..part_count {
            let entry: [u8; 12] = body.array()?;
            let mut c = Cursor { bytes: &entry };
            part_triangles.push((c.u32()?, c.u64()?));
        }
        // The counts the merge adds to the file's metadata are the pages' own.
        let sum = |counts: &[u64]| counts.iter().try_fold(0u64, |t, &n| t.checked_add(n));
        let per_part: Vec<u64> = part_triangles.iter().map(|&(_, n)| n).collect();
        if sum(&degree_histogram) != Some(nodes_here)
            || sum(&per_part) != Some(triangles_here)
            || max_depth > u32::from(u16::MAX)
        {
            return Err("a region's counts are not its pages'".into());
        }
        regions.push(RegionPart {
            root: region_root,
            pages,
            degree_histogram,
            max_depth,
            part_triangles,
        });
    }
    Ok(RootPart {
        root,
        top_ids,
        top_nodes,
        top_triangles,
        regions,
        leaves,
        sums,
        sphere,
    })
}

/// The checks the merge relies on for records of a root's top or of an open page: values
/// finite, leaf ranges within the root's `ranks` and triangle corners within the shard's
/// `corners`, at most eight children with ids below `ids_below`, and
/// subtri ranges that follow each other and cover the triangles once (ranges that overlapped
/// would let a small file make the merge copy triangles many times). Links are checked by the
/// merge as it walks them.
fn check_records(
    nodes: &[NodeRecord],
    triangles: &[TriangleRecord],
    ranks: &std::ops::Range<u32>,
    corners: &std::ops::Range<u32>,
    ids_below: u64,
) -> Result<(), String> {
    let mut subtris_at = 0u64;
    for (k, n) in nodes.iter().enumerate() {
        let floats = n.proxy.iter().chain(&n.sphere).chain(&n.cone);
        if !floats
            .chain([&n.error_radius, &n.surface_error])
            .all(|x| x.get().is_finite())
        {
            return Err(format!("node {k} has a value that is not finite"));
        }
        let (begin, end) = (n.leaf_begin.get(), n.leaf_end.get());
        if begin >= end || begin < ranks.start || end > ranks.end {
            return Err(format!("node {k} has leaf range {begin}..{end}"));
        }
        let children_end = u64::from(n.first_child.get()) + u64::from(n.child_count);
        if n.child_count > 8
            || (n.child_count == 0 && n.first_child.get() != NO_NODE)
            || (n.child_count > 0 && children_end > ids_below)
        {
            return Err(format!("node {k} has children out of range"));
        }
        if u64::from(n.subtri_begin.get()) != subtris_at {
            return Err(format!(
                "node {k}'s subtris do not follow the previous node's"
            ));
        }
        subtris_at += u64::from(n.subtri_count.get());
        if subtris_at > triangles.len() as u64 {
            return Err(format!("node {k}'s subtris lie past the triangles"));
        }
    }
    if subtris_at != triangles.len() as u64 {
        return Err("triangles no node owns".into());
    }
    if triangles
        .iter()
        .any(|t| t.corners.iter().any(|c| !corners.contains(&c.get())))
    {
        return Err("a triangle corner past its vertices".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::container::encoded;
    use super::*;
    use vds_import::Scene;

    /// A small scene: a bumpy grid of triangles, some sharing corners across cells.
    fn scene() -> Scene {
        super::super::bumpy_grid(24)
    }

    /// Parts whose bodies are damaged but carry valid checksums (as a hostile file would):
    /// reading them never panics, and neither does merging one that reads with the other
    /// shards' parts (with two shards, pages with triangles across shards among them).
    #[test]
    fn damaged_bodies_with_valid_checksums_never_panic() {
        let mut scene = scene();
        let grid = crate::snap_to_grid(&mut scene);
        for shards in [1, 2] {
            let plan = super::super::plan(
                &scene.positions,
                scene.triangles.len() as u64,
                grid,
                shards,
                // Small pages: a merge of the part lays out regions (a region of pages holds
                // 64 leaves), not the whole tree as its top.
                super::super::PlanMetadata {
                    page_bytes: 256,
                    ..Default::default()
                },
            )
            .unwrap();
            assert!(plan.roots.len() > 2, "{} roots", plan.roots.len());
            let part = super::super::build_shard(&scene, &plan, 0).unwrap();
            let others: Vec<ShardPart> = (1..plan.shard_count())
                .map(|k| super::super::build_shard(&scene, &plan, k).unwrap())
                .collect();
            let open_pages = (0..plan.shard_count())
                .flat_map(|k| super::super::build_shard(&scene, &plan, k).unwrap().roots)
                .flat_map(|r| r.regions)
                .flat_map(|g| g.pages)
                .filter(|p| matches!(p, RegionPage::Open(_)))
                .count();
            // Two shards: pages with triangles across shards, which the merge encodes.
            assert_eq!(open_pages > 0, shards > 1, "{open_pages} open pages");
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("p.vdtpart");
            write_part(&path, &part).unwrap();
            let file = std::fs::read(&path).unwrap();
            // A part's body is stored raw.
            let body = file[HEADER_BYTES as usize..file.len() - TRAILER_BYTES as usize].to_vec();
            let mut seed = 0x9e37_79b9_7f4a_7c15u64;
            let mut random = move || {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                seed
            };
            let (mut read, mut merged) = (0, 0);
            for round in 0..3000 {
                let mut damaged = body.clone();
                match round % 3 {
                    0 => {
                        let at = random() as usize % damaged.len();
                        damaged[at] ^= 1 << (random() % 8);
                    }
                    1 => {
                        let at = random() as usize % (damaged.len() - 4);
                        let value = [0u32, 1, 2, 0xff, u32::MAX, 0x8000_0000][round % 6];
                        damaged[at..at + 4].copy_from_slice(&value.to_le_bytes());
                    }
                    _ => damaged.truncate(random() as usize % damaged.len()),
                }
                let bytes = encoded(PART_MAGIC, 0, plan.id, &damaged);
                // Skimmed as the merge's first pass reads a file: never a panic either, and
                // seeking over a file's bytes finds what reading them does.
                let head = part_head_from_bytes(&bytes, &plan);
                std::fs::write(&path, &bytes).unwrap();
                match (&head, read_part_head(&path, &plan)) {
                    (Ok(read), Ok(sought)) => assert_eq!(*read, sought, "round {round}"),
                    (Err(_), Err(_)) => {}
                    (read, sought) => panic!("round {round}: {read:?} against {sought:?}"),
                }
                let Ok(part) = part_from_bytes(&bytes, &plan) else {
                    continue;
                };
                read += 1;
                // A body that reads whole skims to the same head.
                assert_eq!(
                    head.map(|h| h.head),
                    Ok(PartHead::of(&part).head),
                    "round {round}"
                );
                let mut all = vec![part];
                all.extend(others.iter().cloned());
                if super::super::merge(&plan, all).is_ok() {
                    merged += 1;
                }
            }
            // Flips in float fields leave a readable part: the test reaches the merge.
            assert!(read > 100, "{read} of 3000 damaged parts read");
            assert!(merged > 100, "{merged} merged");
        }
    }
}
