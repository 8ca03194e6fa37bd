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
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    out.put(&(part.roots.len() as u32).to_le_bytes())
        .map_err(io)?;
    for root in &part.roots {
        put_root(&mut out, root).map_err(io)?;
    }
    put_cross(&mut out, &part.cross).map_err(io)?;
    out.finish(PART_MAGIC, part.index, part.plan_id)
}

/// Builds shard `index` of `plan` from its input and writes its part to `path`, each root as
/// soon as it is built (what [`super::build_shard_from`] and [`write_part`] do, without
/// holding every root's records at once). Returns the number of cross-root corners.
pub fn write_shard(
    path: &Path,
    plan: &Plan,
    index: u32,
    input: Vec<SpillTriangle>,
) -> Result<usize, ShardError> {
    let mut out = BodyWriter::create(path)?;
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    if index >= plan.shard_count() {
        return Err(ShardError::InputChanged(format!(
            "shard {index} of a plan of {} shards",
            plan.shard_count()
        )));
    }
    out.put(&(plan.shard_roots(index).len() as u32).to_le_bytes())
        .map_err(io)?;
    let cross = super::build_shard_into(plan, index, input, |root| {
        put_root(&mut out, &root).map_err(io)
    })?;
    put_cross(&mut out, &cross).map_err(io)?;
    out.finish(PART_MAGIC, index, plan.id)?;
    Ok(cross.len())
}

/// One root's entry of a part's body.
fn put_root(out: &mut BodyWriter, root: &RootPart) -> std::io::Result<()> {
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
    out.put(root.triangles.as_bytes())
}

/// The cross-root corners at the end of a part's body.
fn put_cross(out: &mut BodyWriter, cross: &[CrossCorner]) -> std::io::Result<()> {
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
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut header = Vec::with_capacity(HEADER_BYTES);
    std::fs::File::open(path)
        .map_err(io)?
        .take(HEADER_BYTES as u64)
        .read_to_end(&mut header)
        .map_err(io)?;
    parse_header(&header, magic).map_err(|reason| ShardError::BadPart {
        path: path.to_path_buf(),
        reason,
    })
}

/// The header at the start of `data`, checked.
fn parse_header(data: &[u8], magic: [u8; 8]) -> Result<PartHeader, String> {
    let Some(header) = data.get(..HEADER_BYTES) else {
        return Err("truncated: shorter than a part header".into());
    };
    if header[..8] != magic {
        return Err(if magic == PART_MAGIC {
            "not a .vdtpart file (wrong magic)".into()
        } else {
            "not a shard input file (wrong magic)".into()
        });
    }
    let u32_at = |at: usize| u32::from_le_bytes(header[at..at + 4].try_into().expect("4 bytes"));
    let u64_at = |at: usize| u64::from_le_bytes(header[at..at + 8].try_into().expect("8 bytes"));
    if xxh3_64(&header[..40]) != u64_at(40) {
        return Err("damaged header (checksum mismatch)".into());
    }
    if u32_at(8) != PART_VERSION {
        return Err(format!(
            "part format {}, this build reads {PART_VERSION}",
            u32_at(8)
        ));
    }
    Ok(PartHeader {
        index: u32_at(12),
        plan_id: u64_at(16),
        body_bytes: u64_at(24),
        body_checksum: u64_at(32),
    })
}

/// The most body bytes shard `index` of `plan` can hold: a subtree has fewer than twice its
/// vertices in nodes, a triangle is stored once, and a triangle has three corners.
fn body_limit(plan: &Plan, index: u32) -> u64 {
    let roots = plan.shard_roots(index);
    let vertices: u64 = roots
        .clone()
        .map(|r| {
            let n = plan.root_node(r);
            u64::from(n.leaf_end - n.leaf_begin)
        })
        .sum();
    12 + roots.len() as u64 * (12 + SUMS_BYTES as u64)
        + 2 * vertices * NODE_BYTES as u64
        + plan.triangles * (TRIANGLE_BYTES as u64 + 3 * CROSS_BYTES as u64)
}

/// Reads part file `path`, which must be a shard of `plan`, and checks every index it holds.
pub fn read_part(path: &Path, plan: &Plan) -> Result<ShardPart, ShardError> {
    let bad = |reason: String| ShardError::BadPart {
        path: path.to_path_buf(),
        reason,
    };
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    let header = read_header(path, PART_MAGIC)?;
    // The most a shard's body can compress to, so that a file is read whole only when its
    // size is plausible (what it states is checked in `part_from_bytes`).
    let most = HEADER_BYTES as u64
        + if header.index < plan.shard_count() {
            zstd::zstd_safe::compress_bound(body_limit(plan, header.index) as usize) as u64
        } else {
            0
        };
    let size = std::fs::metadata(path).map_err(io)?.len();
    if size > most {
        return Err(bad(format!("{size} bytes, more than its shard can hold")));
    }
    let data = std::fs::read(path).map_err(io)?;
    part_from_bytes(&data, plan).map_err(bad)
}

/// A part from the bytes of a `.vdtpart` file, which must be a shard of `plan`; every index
/// it holds is checked. (What [`read_part`] does once it has read the file.)
pub fn part_from_bytes(data: &[u8], plan: &Plan) -> Result<ShardPart, String> {
    let header = parse_header(data, PART_MAGIC)?;
    if header.plan_id != plan.id {
        return Err(format!(
            "built for another plan (id {:016x}, this plan is {:016x})",
            header.plan_id, plan.id
        ));
    }
    if header.index >= plan.shard_count() {
        return Err(format!(
            "shard {} of a plan of {} shards",
            header.index,
            plan.shard_count()
        ));
    }
    let limit = body_limit(plan, header.index);
    if header.body_bytes > limit {
        return Err(format!(
            "states a body of {} bytes, more than its shard can hold ({limit})",
            header.body_bytes
        ));
    }
    // Bounded by the plan above: decoded into a buffer of exactly the stated size.
    let mut body = vec![0u8; header.body_bytes as usize];
    decode_body(&data[HEADER_BYTES..], &header, &mut body)?;
    parse_body(&body, plan, header)
}

/// Decodes a body of exactly `out.len()` bytes from the zstd stream `compressed` and checks
/// it against the header's checksum.
fn decode_body(
    compressed: impl std::io::Read,
    header: &PartHeader,
    out: &mut [u8],
) -> Result<(), String> {
    use std::io::Read;
    let mut decoder =
        zstd::stream::read::Decoder::new(compressed).map_err(|e| format!("damaged body ({e})"))?;
    decoder
        .read_exact(out)
        .map_err(|e| format!("truncated or damaged body ({e})"))?;
    let mut rest = [0u8; 1];
    let more = decoder
        .read(&mut rest)
        .map_err(|e| format!("damaged body ({e})"))?;
    if more != 0 {
        return Err("a body longer than its header states".into());
    }
    if xxh3_64(out) != header.body_checksum {
        return Err("truncated or damaged body (checksum mismatch)".into());
    }
    Ok(())
}

/// Reads the body of a file whose header is `header` into `out` (the body's stated length),
/// streaming from the file, checked against its checksum.
fn read_body_into(path: &Path, header: &PartHeader, out: &mut [u8]) -> Result<(), ShardError> {
    use std::io::Seek;
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    file.seek(std::io::SeekFrom::Start(HEADER_BYTES as u64))
        .map_err(io)?;
    decode_body(std::io::BufReader::new(file), header, out).map_err(|reason| ShardError::BadPart {
        path: path.to_path_buf(),
        reason,
    })
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
        let floats = n.proxy.iter().chain(&n.sphere).chain(&n.cone);
        if !floats
            .chain([&n.error_radius, &n.surface_error])
            .all(|x| x.get().is_finite())
        {
            return Err(format!("node {id} has a value that is not finite"));
        }
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
            if end != begin + 1
                || n.first_child.get() != NO_NODE
                || std::mem::replace(&mut seen[begin as usize], true)
            {
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
    // A tree: every node but the root is the child of exactly the node its parent field
    // names, one level below it, and children partition their parent's ranks in order.
    let mut adopted = vec![false; nodes.len()];
    for (id, n) in nodes.iter().enumerate() {
        let first = n.first_child.get() as usize;
        let mut at = n.leaf_begin.get();
        for c in first..first + usize::from(n.child_count) {
            let child = &nodes[c];
            if child.parent.get() as usize != id
                || child.depth.get() != n.depth.get().wrapping_add(1)
                || child.leaf_begin.get() != at
                || std::mem::replace(&mut adopted[c], true)
            {
                return Err(format!("node {c} is not a child of node {id}"));
            }
            at = child.leaf_end.get();
        }
        if n.child_count > 0 && at != n.leaf_end.get() {
            return Err(format!("node {id}'s children do not cover its ranks"));
        }
    }
    if root.depth.get() != 0 || adopted.iter().skip(1).any(|&a| !a) {
        return Err("a node outside the tree".into());
    }
    if triangles
        .iter()
        .any(|t| t.corners.iter().any(|c| c.get() >= leaves))
    {
        return Err("a triangle corner past its vertices".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small scene: a bumpy grid of triangles, some sharing corners across cells.
    fn scene() -> Scene {
        let n = 24u32;
        let mut scene = Scene::default();
        for y in 0..n {
            for x in 0..n {
                let z = ((x * 7 + y * 3) % 5) as f32 * 0.1;
                scene.positions.push([x as f32, y as f32, z]);
            }
        }
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let v = y * n + x;
                scene.triangles.push([v, v + 1, v + n]);
                scene.triangles.push([v + 1, v + n + 1, v + n]);
            }
        }
        scene.triangle_parts = vec![0; scene.triangles.len()];
        scene.part_names = vec!["grid".into()];
        scene
    }

    /// Parts whose bodies are damaged but carry valid checksums (as a hostile file would):
    /// reading them never panics, and neither does merging and encoding one that reads.
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
                Default::default(),
            )
            .unwrap();
            let part = super::super::build_shard(&scene, &plan, 0).unwrap();
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("p.vdtpart");
            write_part(&path, &part).unwrap();
            let file = std::fs::read(&path).unwrap();
            let body = zstd::decode_all(&file[HEADER_BYTES..]).unwrap();
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
                let mut bytes = header_bytes(
                    PART_MAGIC,
                    0,
                    plan.id,
                    damaged.len() as u64,
                    xxh3_64(&damaged),
                );
                bytes.extend(zstd::encode_all(&damaged[..], 1).unwrap());
                let Ok(part) = part_from_bytes(&bytes, &plan) else {
                    continue;
                };
                read += 1;
                if shards == 1
                    && let Ok(content) = super::super::merge(&plan, vec![part])
                {
                    merged += 1;
                    let _ = vds_format::encode(&content, &Default::default());
                }
            }
            // Flips in float fields leave a readable part: the test reaches the merge.
            assert!(read > 100, "{read} of 3000 damaged parts read");
            if shards == 1 {
                assert!(merged > 100, "{merged} merged");
            }
        }
    }
}
