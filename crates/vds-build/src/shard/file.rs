//! The `.vdtpart` file: one shard's output, read by the merge.
//!
//! A 48-byte header, then one zstd frame of the body. Every number is little-endian.
//!
//! | header bytes | field |
//! |---|---|
//! | 0..8 | [`PART_MAGIC`] |
//! | 8..12 | format version (1) |
//! | 12..16 | shard index |
//! | 16..24 | the plan's id |
//! | 24..32 | body length, uncompressed |
//! | 32..40 | XXH3-64 of the uncompressed body |
//! | 40..48 | XXH3-64 of header bytes 0..40 |
//!
//! The body: the root count (`u32`); per root its index, node count and triangle count
//! (`u32` each), its accumulated sums and sphere ([`SUMS_BYTES`]), its node records and its
//! triangle records (the `.vdt` record layouts); then the cross-corner count (`u64`) and the
//! cross corners, 25 bytes each (triangle `u64`, corner `u8`, root, rank, part, owner `u32`).
//!
//! The reader treats the file as hostile: the body's length is bounded by what the plan
//! allows the shard to hold before anything is allocated, the checksums are checked, and
//! every index a record holds is checked against the plan and the part before the merge uses
//! it.

use std::path::{Path, PathBuf};

use vds_format::{NO_NODE, NodeRecord, TriangleRecord};
use vds_import::Scene;
use xxhash_rust::xxh3::xxh3_64;
use zerocopy::{FromBytes, FromZeros, IntoBytes};

use super::part::{CrossCorner, RootPart, ShardPart, SpillTriangle};
use super::{Plan, ShardError};
use crate::bounds::{Aabb, NormalCone};
use crate::build::{Accumulator, Sphere};
use crate::quadric::Quadric;

/// The first eight bytes of a `.vdtpart` file.
pub const PART_MAGIC: [u8; 8] = *b"VDTPART\0";
const PART_VERSION: u32 = 1;
const HEADER_BYTES: usize = 48;
/// Bytes of a root's sums and sphere in the body.
const SUMS_BYTES: usize = 10 * 8 + 3 * 8 + 12 * 4 + 4 * 8 + 1 + 4 * 8 + 4 * 4;
const CROSS_BYTES: usize = 8 + 1 + 4 * 4;
const NODE_BYTES: usize = vds_format::layout::NODE_BYTES;
const TRIANGLE_BYTES: usize = vds_format::layout::TRIANGLE_BYTES;
/// zstd level of parts: they are read once, by the merge.
const PART_ZSTD_LEVEL: i32 = 1;

/// Writes `part` to `path` (a temporary file, then renamed).
pub fn write_part(path: &Path, part: &ShardPart) -> Result<(), ShardError> {
    let mut out = BodyWriter::create(path)?;
    let write = |out: &mut BodyWriter| -> std::io::Result<()> {
        out.put(&(part.roots.len() as u32).to_le_bytes())?;
        for root in &part.roots {
            for n in [
                root.root,
                root.nodes.len() as u32,
                root.triangles.len() as u32,
            ] {
                out.put(&n.to_le_bytes())?;
            }
            let mut sums = Vec::with_capacity(SUMS_BYTES);
            put_sums(&mut sums, &root.sums, &root.sphere);
            out.put(&sums)?;
            out.put(root.nodes.as_bytes())?;
            out.put(root.triangles.as_bytes())?;
        }
        out.put(&(part.cross.len() as u64).to_le_bytes())?;
        let mut record = Vec::with_capacity(CROSS_BYTES);
        for c in &part.cross {
            record.clear();
            record.extend_from_slice(&c.triangle.to_le_bytes());
            record.push(c.corner);
            for n in [c.root, c.rank, c.part, c.owner] {
                record.extend_from_slice(&n.to_le_bytes());
            }
            out.put(&record)?;
        }
        Ok(())
    };
    write(&mut out).map_err(|source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    out.finish(PART_MAGIC, part.index, part.plan_id)
}

/// A body streamed through zstd into a temporary file beside its target, hashed on the way;
/// [`BodyWriter::finish`] writes the header in front and renames the file into place.
struct BodyWriter {
    path: PathBuf,
    out: zstd::stream::write::Encoder<'static, std::io::BufWriter<tempfile::NamedTempFile>>,
    hasher: xxhash_rust::xxh3::Xxh3,
    bytes: u64,
}

impl BodyWriter {
    fn create(path: &Path) -> Result<BodyWriter, ShardError> {
        use std::io::Write;
        let io = |source| ShardError::Io {
            path: path.to_path_buf(),
            source,
        };
        vds_format::resolve_output(path)?;
        let dir = path
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let mut file = tempfile::NamedTempFile::new_in(dir).map_err(io)?;
        file.write_all(&[0u8; HEADER_BYTES]).map_err(io)?;
        let out = zstd::stream::write::Encoder::new(std::io::BufWriter::new(file), PART_ZSTD_LEVEL)
            .map_err(io)?;
        Ok(BodyWriter {
            path: path.to_path_buf(),
            out,
            hasher: xxhash_rust::xxh3::Xxh3::new(),
            bytes: 0,
        })
    }

    fn put(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        use std::io::Write;
        self.out.write_all(bytes)?;
        self.hasher.update(bytes);
        self.bytes += bytes.len() as u64;
        Ok(())
    }

    fn finish(self, magic: [u8; 8], index: u32, plan_id: u64) -> Result<(), ShardError> {
        use std::io::{Seek, Write};
        let path = self.path;
        let io = |source| ShardError::Io {
            path: path.clone(),
            source,
        };
        let header = header_bytes(magic, index, plan_id, self.bytes, self.hasher.digest());
        let mut file = self
            .out
            .finish()
            .map_err(io)?
            .into_inner()
            .map_err(|e| io(e.into_error()))?;
        file.rewind().map_err(io)?;
        file.write_all(&header).map_err(io)?;
        file.as_file().sync_all().map_err(io)?;
        file.persist(&path).map_err(|e| io(e.error))?;
        Ok(())
    }
}

/// A header: `magic`, the version, the shard's index, the plan's id, the body's length and
/// checksum, and the header's own checksum.
fn header_bytes(
    magic: [u8; 8],
    index: u32,
    plan_id: u64,
    body_bytes: u64,
    body_checksum: u64,
) -> Vec<u8> {
    let mut header = Vec::with_capacity(HEADER_BYTES);
    header.extend_from_slice(&magic);
    header.extend_from_slice(&PART_VERSION.to_le_bytes());
    header.extend_from_slice(&index.to_le_bytes());
    header.extend_from_slice(&plan_id.to_le_bytes());
    header.extend_from_slice(&body_bytes.to_le_bytes());
    header.extend_from_slice(&body_checksum.to_le_bytes());
    let checksum = xxh3_64(&header);
    header.extend_from_slice(&checksum.to_le_bytes());
    header
}

/// The header of a part or spill file: which shard of which plan it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct PartHeader {
    index: u32,
    plan_id: u64,
    body_bytes: u64,
    body_checksum: u64,
}

/// Which shard of which plan a part file is (its index and the plan's id), from its header
/// alone: a merge checks the set of parts before it reads any.
pub fn part_header(path: &Path) -> Result<(u32, u64), ShardError> {
    read_header(path, PART_MAGIC).map(|h| (h.index, h.plan_id))
}

/// Reads and checks the header of a file that should start with `magic`.
fn read_header(path: &Path, magic: [u8; 8]) -> Result<PartHeader, ShardError> {
    use std::io::Read;
    let bad = |reason: &str| ShardError::BadPart {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    };
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut header = [0u8; HEADER_BYTES];
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut filled = 0;
    while filled < HEADER_BYTES {
        match file.read(&mut header[filled..]).map_err(io)? {
            0 => return Err(bad("truncated: shorter than a part header")),
            n => filled += n,
        }
    }
    if header[..8] != magic {
        return Err(bad(if magic == PART_MAGIC {
            "not a .vdtpart file (wrong magic)"
        } else {
            "not a shard input file (wrong magic)"
        }));
    }
    let u32_at = |at: usize| u32::from_le_bytes(header[at..at + 4].try_into().expect("4 bytes"));
    let u64_at = |at: usize| u64::from_le_bytes(header[at..at + 8].try_into().expect("8 bytes"));
    if xxh3_64(&header[..40]) != u64_at(40) {
        return Err(bad("damaged header (checksum mismatch)"));
    }
    if u32_at(8) != PART_VERSION {
        return Err(bad(&format!(
            "part format {}, this build reads {PART_VERSION}",
            u32_at(8)
        )));
    }
    Ok(PartHeader {
        index: u32_at(12),
        plan_id: u64_at(16),
        body_bytes: u64_at(24),
        body_checksum: u64_at(32),
    })
}

/// Reads part file `path`, which must be a shard of `plan`, and checks every index it holds.
pub fn read_part(path: &Path, plan: &Plan) -> Result<ShardPart, ShardError> {
    let bad = |reason: String| ShardError::BadPart {
        path: path.to_path_buf(),
        reason,
    };
    let header = read_header(path, PART_MAGIC)?;
    if header.plan_id != plan.id {
        return Err(bad(format!(
            "built for another plan (id {:016x}, this plan is {:016x})",
            header.plan_id, plan.id
        )));
    }
    if header.index >= plan.shard_count() {
        return Err(bad(format!(
            "shard {} of a plan of {} shards",
            header.index,
            plan.shard_count()
        )));
    }
    let roots = plan.shard_roots(header.index);
    // The most a shard's body can hold: a subtree has fewer than twice its vertices in nodes,
    // a triangle is stored once, and a triangle has three corners.
    let vertices: u64 = roots
        .clone()
        .map(|r| {
            let n = plan.root_node(r);
            u64::from(n.leaf_end - n.leaf_begin)
        })
        .sum();
    let limit = 12
        + roots.len() as u64 * (12 + SUMS_BYTES as u64)
        + 2 * vertices * NODE_BYTES as u64
        + plan.triangles * (TRIANGLE_BYTES as u64 + 3 * CROSS_BYTES as u64);
    if header.body_bytes > limit {
        return Err(bad(format!(
            "states a body of {} bytes, more than its shard can hold ({limit})",
            header.body_bytes
        )));
    }
    // The length is bounded by the plan above: read into a buffer of exactly that size.
    let mut body = vec![0u8; header.body_bytes as usize];
    read_body_into(path, &header, &mut body)?;
    let part = parse_body(&body, plan, header).map_err(bad)?;
    Ok(part)
}

/// Reads the body of a file whose header is `header` into `out` (the body's stated length),
/// checked against its checksum.
fn read_body_into(path: &Path, header: &PartHeader, out: &mut [u8]) -> Result<(), ShardError> {
    use std::io::{Read, Seek};
    let bad = |reason: String| ShardError::BadPart {
        path: path.to_path_buf(),
        reason,
    };
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    file.seek(std::io::SeekFrom::Start(HEADER_BYTES as u64))
        .map_err(io)?;
    let mut decoder = zstd::stream::read::Decoder::new(file).map_err(io)?;
    decoder
        .read_exact(out)
        .map_err(|e| bad(format!("truncated or damaged body ({e})")))?;
    let mut rest = [0u8; 1];
    if decoder
        .read(&mut rest)
        .map_err(|e| bad(format!("damaged body ({e})")))?
        != 0
    {
        return Err(bad("a body longer than its header states".into()));
    }
    if xxh3_64(out) != header.body_checksum {
        return Err(bad("truncated or damaged body (checksum mismatch)".into()));
    }
    Ok(())
}

/// The first eight bytes of a shard's input file.
pub const SPILL_MAGIC: [u8; 8] = *b"VDTSPILL";
const SPILL_BYTES: usize = size_of::<SpillTriangle>();

/// Writes every shard's input file (`paths[k]` for shard `k`) in one pass over `scene`'s
/// triangles: each goes to the shards its corners lie in (`root_of`, from
/// [`super::roots_of_vertices`]). Each file is written beside its target and renamed into place
/// when complete.
pub fn write_spills(
    scene: &Scene,
    plan: &Plan,
    root_of: &[u32],
    paths: &[PathBuf],
) -> Result<(), ShardError> {
    let shard_of_root: Vec<u32> = (0..plan.shard_count())
        .flat_map(|k| plan.shard_roots(k).map(move |_| k))
        .collect();
    let mut spills = paths
        .iter()
        .map(|path| BodyWriter::create(path))
        .collect::<Result<Vec<_>, _>>()?;
    for t in 0..scene.triangles.len() {
        let mut shards = scene.triangles[t].map(|v| shard_of_root[root_of[v as usize] as usize]);
        shards.sort_unstable();
        let record = super::part::spill_triangle(scene, t);
        for (k, &shard) in shards.iter().enumerate() {
            if k > 0 && shards[k - 1] == shard {
                continue;
            }
            let spill = &mut spills[shard as usize];
            spill
                .put(record.as_bytes())
                .map_err(|source| ShardError::Io {
                    path: paths[shard as usize].clone(),
                    source,
                })?;
        }
    }
    for (k, spill) in spills.into_iter().enumerate() {
        spill.finish(SPILL_MAGIC, k as u32, plan.id)?;
    }
    Ok(())
}

/// Reads shard `index`'s input file, which must be for `plan`.
pub fn read_spill(path: &Path, plan: &Plan, index: u32) -> Result<Vec<SpillTriangle>, ShardError> {
    let bad = |reason: String| ShardError::BadPart {
        path: path.to_path_buf(),
        reason,
    };
    let header = read_header(path, SPILL_MAGIC)?;
    if header.plan_id != plan.id || header.index != index {
        return Err(bad(format!(
            "the input of shard {} of plan {:016x}, not of shard {index} of this plan ({:016x})",
            header.index, header.plan_id, plan.id
        )));
    }
    if header.body_bytes % SPILL_BYTES as u64 != 0
        || header.body_bytes / SPILL_BYTES as u64 > plan.triangles
    {
        return Err(bad(format!(
            "states {} bytes of triangles; the plan has {} triangles",
            header.body_bytes, plan.triangles
        )));
    }
    let count = (header.body_bytes / SPILL_BYTES as u64) as usize;
    let mut triangles = vec![SpillTriangle::new_zeroed(); count];
    read_body_into(path, &header, triangles.as_mut_bytes())?;
    Ok(triangles)
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
    fn records<T: FromBytes + zerocopy::Immutable + zerocopy::KnownLayout + Clone>(
        &mut self,
        count: usize,
        size: usize,
    ) -> Result<Vec<T>, String> {
        let bytes = self.take(count.checked_mul(size).ok_or("record count overflows")?)?;
        let records = <[T]>::ref_from_bytes(bytes).map_err(|_| "misaligned records")?;
        Ok(records.to_vec())
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
    Ok((sums, sphere))
}

fn parse_body(body: &[u8], plan: &Plan, header: PartHeader) -> Result<ShardPart, String> {
    let mut c = Cursor { bytes: body };
    let expected = plan.shard_roots(header.index);
    let root_count = c.u32()?;
    if root_count != expected.len() as u32 {
        return Err(format!(
            "{root_count} roots, the plan gives this shard {}",
            expected.len()
        ));
    }
    let mut roots = Vec::with_capacity(expected.len());
    for root in expected {
        let (index, node_count, triangle_count) = (c.u32()?, c.u32()?, c.u32()?);
        if index != root {
            return Err(format!("root {index} where the plan has root {root}"));
        }
        let node = plan.root_node(root);
        let leaves = node.leaf_end - node.leaf_begin;
        if node_count == 0 || u64::from(node_count) > 2 * u64::from(leaves) {
            return Err(format!(
                "root {root}: {node_count} nodes for {leaves} vertices"
            ));
        }
        let (sums, sphere) = get_sums(&mut c)?;
        let nodes: Vec<NodeRecord> = c.records(node_count as usize, NODE_BYTES)?;
        let triangles: Vec<TriangleRecord> = c.records(triangle_count as usize, TRIANGLE_BYTES)?;
        check_subtree(&nodes, &triangles, leaves).map_err(|e| format!("root {root}: {e}"))?;
        roots.push(RootPart {
            root,
            nodes,
            triangles,
            sums,
            sphere,
        });
    }
    let cross_count = c.u64()?;
    if cross_count > c.bytes.len() as u64 / CROSS_BYTES as u64 {
        return Err("truncated body".into());
    }
    let mut cross = Vec::with_capacity(cross_count as usize);
    for _ in 0..cross_count {
        let corner = CrossCorner {
            triangle: c.u64()?,
            corner: c.u8()?,
            root: c.u32()?,
            rank: c.u32()?,
            part: c.u32()?,
            owner: c.u32()?,
        };
        let Some(local) = roots.iter().find(|r| r.root == corner.root) else {
            return Err(format!(
                "a cross corner under root {}, not this shard's",
                corner.root
            ));
        };
        let leaves = local.nodes[0].leaf_end.get();
        if corner.triangle >= plan.triangles
            || corner.corner > 2
            || corner.rank >= leaves
            || (corner.owner != u32::MAX && corner.owner as usize >= local.nodes.len())
        {
            return Err(format!(
                "cross corner of triangle {} out of range",
                corner.triangle
            ));
        }
        cross.push(corner);
    }
    if !c.bytes.is_empty() {
        return Err("bytes after the body".into());
    }
    Ok(ShardPart {
        plan_id: header.plan_id,
        index: header.index,
        roots,
        cross,
    })
}

/// The checks the merge relies on: links and ranges inside the subtree, and leaves that hold
/// every rank once.
fn check_subtree(
    nodes: &[NodeRecord],
    triangles: &[TriangleRecord],
    leaves: u32,
) -> Result<(), String> {
    let count = nodes.len() as u64;
    let root = &nodes[0];
    if root.parent.get() != NO_NODE || root.leaf_begin.get() != 0 || root.leaf_end.get() != leaves {
        return Err("its root does not span its vertices".into());
    }
    let mut seen = vec![false; leaves as usize];
    for (id, n) in nodes.iter().enumerate() {
        let (begin, end) = (n.leaf_begin.get(), n.leaf_end.get());
        if begin >= end || end > leaves {
            return Err(format!("node {id} has leaf range {begin}..{end}"));
        }
        if id > 0 && u64::from(n.parent.get()) >= count {
            return Err(format!("node {id} has no parent"));
        }
        let subtris = u64::from(n.subtri_begin.get()) + u64::from(n.subtri_count.get());
        if subtris > triangles.len() as u64 {
            return Err(format!("node {id}'s subtris lie past the triangles"));
        }
        if n.child_count == 0 {
            if end != begin + 1 || std::mem::replace(&mut seen[begin as usize], true) {
                return Err(format!("leaf {id} does not hold one rank of its own"));
            }
        } else if n.child_count > 8
            || u64::from(n.first_child.get()) + u64::from(n.child_count) > count
            || n.first_child.get() as usize <= id
        {
            return Err(format!("node {id} has children out of range"));
        }
    }
    if seen.iter().any(|&s| !s) {
        return Err("a rank no leaf holds".into());
    }
    if triangles
        .iter()
        .any(|t| t.corners.iter().any(|c| c.get() >= leaves))
    {
        return Err("a triangle corner past its vertices".into());
    }
    Ok(())
}
