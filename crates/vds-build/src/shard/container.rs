//! The layout both of the sharded build's files share (a shard's input, `.vdtin`, and its
//! part, `.vdtpart`): a 32-byte header, the body, and a 24-byte trailer. Every number is
//! little-endian.
//!
//! | bytes | field |
//! |---|---|
//! | header 0..8 | magic: [`super::INPUT_MAGIC`] or [`super::PART_MAGIC`] |
//! | header 8..12 | format version (5) |
//! | header 12..16 | shard index |
//! | header 16..24 | the plan's id |
//! | header 24..32 | XXH3-64 of header bytes 0..24 |
//! | trailer 0..8 | body length, uncompressed |
//! | trailer 8..16 | XXH3-64 of the uncompressed body |
//! | trailer 16..24 | XXH3-64 of trailer bytes 0..16 |
//!
//! The trailer comes last so that a body is streamed into the file as it is made, through
//! [`vds_format::AtomicFile`] (a temporary file, renamed into place when complete); a shard
//! input's header is rewritten in place once its plan is sealed ([`restamp`]). A reader
//! checks the header and trailer, bounds the stated length by what its caller allows before
//! it allocates, decodes exactly that many bytes and checks the checksum.
//!
//! How the body is stored depends on the kind of file ([`Codec::of`]):
//!
//! - A shard input's body (its records in shuffled blocks, [`super::input_file`]) is an LZ4
//!   frame (the LZ4 frame format, independent of this crate; independent blocks of 64 KiB,
//!   no checksums of LZ4's own: the trailer's covers the body). Each input is written once
//!   (again only where a build within a limit cuts its plan finer) and read once, so the
//!   codec is chosen for speed over size: on 60-byte records of
//!   triangles with their corners' positions (a shard input's, before its vertices were
//!   stored apart) LZ4 compresses twice as fast as zstd at level −1 and decodes four times
//!   as fast (955 against 470 MB/s, 4.9 against 1.3 GB/s; `lz4 -b1` with its own 4 MiB
//!   blocks and `zstd -b --fast=1`), for files 1.6 times the size (2.8× against 4.5×), and
//!   the 20 M scene's build within 512 MiB took a tenth less time. Blocks of 64 KiB keep an
//!   encoder's buffers at about 150 KB: a plan writes many files at once.
//! - A part's body is stored as it is. Most of it is pages already compressed with zstd and
//!   leaf positions (float bits), on which LZ4 gained only a factor 1.6 (the 20 M scene's
//!   parts, 42 MB a shard) while its decoding was the largest single cost of the merge, on
//!   the merge's one reading thread.

use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

use xxhash_rust::xxh3::{Xxh3, xxh3_64};
use zerocopy::{FromBytes, IntoBytes};

use super::ShardError;

const VERSION: u32 = 5;
/// Bytes before the body.
pub(crate) const HEADER_BYTES: u64 = 32;
/// Bytes after the body.
pub(crate) const TRAILER_BYTES: u64 = 24;

/// Whether a file the sharded build writes must survive a crash of the machine once it is in
/// place.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Durability {
    /// Synced before it is renamed into place, and a header rewritten in place synced: what a
    /// later job reads (`vds-build plan`'s inputs, `vds-build shard`'s part).
    Synced,
    /// Renamed into place unsynced ([`vds_format::AtomicFile::commit_unsynced`]): what a build
    /// within `--memory-limit` writes for itself in its own temporary folder, which a crash
    /// makes worthless anyway (the 20 M scene's build in 512 MiB spent 0.4 s in syncs, its
    /// output's included, and took about 0.2 s less without these).
    Transient,
}

/// How a file's body is stored (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Codec {
    /// One LZ4 frame.
    Lz4,
    /// The bytes themselves.
    Raw,
}

impl Codec {
    /// The codec of the files that start with `magic`: parts are stored raw, inputs in LZ4.
    pub(crate) fn of(magic: [u8; 8]) -> Codec {
        debug_assert!(magic == super::PART_MAGIC || magic == super::INPUT_MAGIC);
        if magic == super::PART_MAGIC {
            Codec::Raw
        } else {
            Codec::Lz4
        }
    }
}

/// Where a body being written goes: through an LZ4 frame encoder, or straight to the file.
enum BodyOut {
    Lz4(lz4_flex::frame::FrameEncoder<vds_format::AtomicFile>),
    Raw(vds_format::AtomicFile),
}

impl BodyOut {
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        match self {
            BodyOut::Lz4(out) => out.write_all(bytes),
            BodyOut::Raw(out) => out.write_all(bytes),
        }
    }

    /// Ends the body and hands back the file.
    fn finish(self) -> std::io::Result<vds_format::AtomicFile> {
        match self {
            BodyOut::Lz4(out) => out.finish().map_err(Into::into),
            BodyOut::Raw(out) => Ok(out),
        }
    }
}

/// A new LZ4 frame encoder over `out`: 64 KiB blocks, no checksums of its own.
fn encoder<W: Write>(out: W) -> lz4_flex::frame::FrameEncoder<W> {
    let info = lz4_flex::frame::FrameInfo::new().block_size(lz4_flex::frame::BlockSize::Max64KB);
    lz4_flex::frame::FrameEncoder::with_frame_info(info, out)
}

/// Which shard of which plan a file is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Header {
    pub(crate) index: u32,
    pub(crate) plan_id: u64,
}

/// The body's stated length and checksum.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Trailer {
    pub(crate) body_bytes: u64,
    pub(crate) body_checksum: u64,
}

/// A file being written: the body streamed (through LZ4 where its [`Codec`] says so) into an
/// [`vds_format::AtomicFile`] and hashed on the way; [`BodyWriter::finish`] adds the trailer
/// and renames it into place.
pub(crate) struct BodyWriter {
    path: PathBuf,
    durability: Durability,
    out: BodyOut,
    hasher: Xxh3,
    bytes: u64,
}

impl BodyWriter {
    /// Starts the file `path` for shard `index` of plan `plan_id`.
    pub(crate) fn create(
        path: &Path,
        magic: [u8; 8],
        index: u32,
        plan_id: u64,
        durability: Durability,
    ) -> Result<BodyWriter, ShardError> {
        let io = |source| ShardError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut file = vds_format::AtomicFile::create(path)?;
        file.write_all(&header_bytes(magic, index, plan_id))
            .map_err(io)?;
        let out = match Codec::of(magic) {
            Codec::Lz4 => BodyOut::Lz4(encoder(file)),
            Codec::Raw => BodyOut::Raw(file),
        };
        Ok(BodyWriter {
            path: path.to_path_buf(),
            durability,
            out,
            hasher: Xxh3::new(),
            bytes: 0,
        })
    }

    /// Appends to the body.
    pub(crate) fn put(&mut self, bytes: &[u8]) -> Result<(), ShardError> {
        self.out.write_all(bytes).map_err(|source| ShardError::Io {
            path: self.path.clone(),
            source,
        })?;
        self.hasher.update(bytes);
        self.bytes += bytes.len() as u64;
        Ok(())
    }

    /// Ends the body, writes the trailer and renames the file into place.
    pub(crate) fn finish(self) -> Result<(), ShardError> {
        let io = |source| ShardError::Io {
            path: self.path.clone(),
            source,
        };
        let mut file = self.out.finish().map_err(io)?;
        let mut trailer = Vec::with_capacity(TRAILER_BYTES as usize);
        trailer.extend_from_slice(&self.bytes.to_le_bytes());
        trailer.extend_from_slice(&self.hasher.digest().to_le_bytes());
        trailer.extend_from_slice(&xxh3_64(&trailer).to_le_bytes());
        file.write_all(&trailer).map_err(io)?;
        match self.durability {
            Durability::Synced => file.commit()?,
            Durability::Transient => file.commit_unsynced()?,
        }
        Ok(())
    }
}

/// The header of a file for shard `index` of plan `plan_id` (see the module documentation).
fn header_bytes(magic: [u8; 8], index: u32, plan_id: u64) -> Vec<u8> {
    let mut header = Vec::with_capacity(HEADER_BYTES as usize);
    header.extend_from_slice(&magic);
    header.extend_from_slice(&VERSION.to_le_bytes());
    header.extend_from_slice(&index.to_le_bytes());
    header.extend_from_slice(&plan_id.to_le_bytes());
    header.extend_from_slice(&xxh3_64(&header).to_le_bytes());
    header
}

/// Rewrites the header of the file at `path`, which must be the one for shard `index` of
/// plan `written_for`, to name plan `plan_id`: the plan's id covers what writing the files
/// found (its shards' triangle counts), so the files are written first and named for it
/// after. The header is rewritten in place, and synced where `durability` says (before the
/// plan is written, so that a plan on disk has its inputs); a crash before the write
/// reaches the disk leaves a file naming the other plan (or a header whose checksum fails),
/// which the plan's shards refuse.
pub(crate) fn restamp(
    path: &Path,
    magic: [u8; 8],
    what: &str,
    (index, written_for): (u32, u64),
    plan_id: u64,
    durability: Durability,
) -> Result<(), ShardError> {
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = std::fs::File::options()
        .read(true)
        .write(true)
        .open(path)
        .map_err(io)?;
    let mut head = [0u8; HEADER_BYTES as usize];
    file.read_exact(&mut head).map_err(io)?;
    let header = parse_header(&head, magic, what).map_err(|reason| ShardError::BadFile {
        path: path.to_path_buf(),
        reason,
    })?;
    if (header.index, header.plan_id) != (index, written_for) {
        return Err(ShardError::BadFile {
            path: path.to_path_buf(),
            reason: format!(
                "the file of shard {} of plan {:016x}, not of shard {index} of plan \
                 {written_for:016x}",
                header.index, header.plan_id
            ),
        });
    }
    file.seek(std::io::SeekFrom::Start(0)).map_err(io)?;
    file.write_all(&header_bytes(magic, index, plan_id))
        .map_err(io)?;
    if durability == Durability::Synced {
        file.sync_data().map_err(io)?;
    }
    Ok(())
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"))
}

fn u64_at(bytes: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(bytes[at..at + 8].try_into().expect("8 bytes"))
}

/// The header at the start of `data` (at least [`HEADER_BYTES`]), checked; `what` names the
/// kind of file in errors.
pub(crate) fn parse_header(data: &[u8], magic: [u8; 8], what: &str) -> Result<Header, String> {
    let Some(header) = data.get(..HEADER_BYTES as usize) else {
        return Err(format!("truncated: shorter than a {what} header"));
    };
    if header[..8] != magic {
        return Err(format!("not a {what} (wrong magic)"));
    }
    if xxh3_64(&header[..24]) != u64_at(header, 24) {
        return Err("damaged header (checksum mismatch)".into());
    }
    if u32_at(header, 8) != VERSION {
        return Err(format!(
            "{what} format {}, this build reads {VERSION}",
            u32_at(header, 8)
        ));
    }
    Ok(Header {
        index: u32_at(header, 12),
        plan_id: u64_at(header, 16),
    })
}

/// The trailer at the end of `data` (a whole file), checked.
pub(crate) fn parse_trailer(data: &[u8]) -> Result<Trailer, String> {
    if (data.len() as u64) < HEADER_BYTES + TRAILER_BYTES {
        return Err("truncated: no room for a trailer".into());
    }
    trailer_from(&data[data.len() - TRAILER_BYTES as usize..])
}

/// The trailer from its [`TRAILER_BYTES`] bytes, checked.
fn trailer_from(trailer: &[u8]) -> Result<Trailer, String> {
    if xxh3_64(&trailer[..16]) != u64_at(trailer, 16) {
        return Err("truncated or damaged (trailer checksum mismatch)".into());
    }
    Ok(Trailer {
        body_bytes: u64_at(trailer, 0),
        body_checksum: u64_at(trailer, 8),
    })
}

/// Reads and checks the header and trailer of file `path`, leaving the body unread.
pub(crate) fn read_ends(
    path: &Path,
    magic: [u8; 8],
    what: &str,
) -> Result<(Header, Trailer), ShardError> {
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    let bad = |reason| ShardError::BadFile {
        path: path.to_path_buf(),
        reason,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut head = Vec::with_capacity(HEADER_BYTES as usize);
    (&mut file)
        .take(HEADER_BYTES)
        .read_to_end(&mut head)
        .map_err(io)?;
    let header = parse_header(&head, magic, what).map_err(bad)?;
    let size = file.metadata().map_err(io)?.len();
    if size < HEADER_BYTES + TRAILER_BYTES {
        return Err(bad("truncated: no room for a trailer".into()));
    }
    let mut tail = [0u8; TRAILER_BYTES as usize];
    file.seek(std::io::SeekFrom::Start(size - TRAILER_BYTES))
        .map_err(io)?;
    file.read_exact(&mut tail).map_err(io)?;
    let trailer = trailer_from(&tail).map_err(bad)?;
    Ok((header, trailer))
}

/// A body read as it is decoded, never past the length its trailer states and hashed on the
/// way, so that records are decoded straight into their own arrays (no copy of the whole
/// body is made); [`BodyReader::finish`] checks that it was read to its end and that its
/// checksum holds. Until then the bytes are unchecked: readers check every value they take.
///
/// A *skimming* reader ([`BodyReader::skimming`]) seeks over what its caller skips
/// ([`BodyReader::skip`]), so it cannot check the checksum: what it reads is whatever the file
/// holds there, checked value by value as always, and only a full read verifies the body.
pub(crate) struct BodyReader<'r> {
    decoder: Box<dyn Read + 'r>,
    /// A skimming reader's file, which skips seek in.
    file: Option<std::io::BufReader<std::fs::File>>,
    hasher: Xxh3,
    left: u64,
    checksum: u64,
}

impl<'r> BodyReader<'r> {
    /// Reads `stored`, the body `trailer` describes as `codec` stores it.
    pub(crate) fn new(stored: impl Read + 'r, codec: Codec, trailer: &Trailer) -> Self {
        let boxed: Box<dyn Read + 'r> = Box::new(stored);
        BodyReader {
            decoder: match codec {
                Codec::Lz4 => Box::new(lz4_flex::frame::FrameDecoder::new(boxed)),
                Codec::Raw => boxed,
            },
            file: None,
            hasher: Xxh3::new(),
            left: trailer.body_bytes,
            checksum: trailer.body_checksum,
        }
    }

    /// A skimming reader of the raw body `trailer` describes, which `file` holds from where it
    /// stands (see the type's documentation).
    pub(crate) fn skimming(file: std::fs::File, trailer: &Trailer) -> BodyReader<'static> {
        BodyReader {
            decoder: Box::new(std::io::empty()),
            file: Some(std::io::BufReader::new(file)),
            hasher: Xxh3::new(),
            left: trailer.body_bytes,
            checksum: trailer.body_checksum,
        }
    }

    /// Passes over the next `n` bytes: a skimming reader seeks, another reads and hashes
    /// them.
    pub(crate) fn skip(&mut self, n: u64) -> Result<(), String> {
        if n > self.left {
            return Err("truncated body".into());
        }
        match &mut self.file {
            Some(file) => {
                // At most the body's length, which the file's size bounds: within `i64`.
                let step = i64::try_from(n).map_err(|_| "truncated body".to_string())?;
                file.seek_relative(step)
                    .map_err(|e| format!("truncated or damaged body ({e})"))?;
                self.left -= n;
            }
            None => {
                let mut scratch = [0u8; 4096];
                let mut rest = n;
                while rest > 0 {
                    let take = rest.min(scratch.len() as u64) as usize;
                    self.read_exact(&mut scratch[..take])?;
                    rest -= take as u64;
                }
            }
        }
        Ok(())
    }

    /// Bytes of the stated body not read yet.
    pub(crate) fn left(&self) -> u64 {
        self.left
    }

    /// Fills `out` from the body.
    pub(crate) fn read_exact(&mut self, out: &mut [u8]) -> Result<(), String> {
        if out.len() as u64 > self.left {
            return Err("truncated body".into());
        }
        let source: &mut dyn Read = match &mut self.file {
            Some(file) => file,
            None => &mut self.decoder,
        };
        source
            .read_exact(out)
            .map_err(|e| format!("truncated or damaged body ({e})"))?;
        self.hasher.update(out);
        self.left -= out.len() as u64;
        Ok(())
    }

    /// The next `N` bytes.
    pub(crate) fn array<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let mut out = [0u8; N];
        self.read_exact(&mut out)?;
        Ok(out)
    }

    /// The next `count` records, allocated only once the body is known to hold them.
    pub(crate) fn records<T: FromBytes + IntoBytes + Clone>(
        &mut self,
        count: usize,
    ) -> Result<Vec<T>, String> {
        let bytes = (count as u64).checked_mul(size_of::<T>() as u64);
        if bytes.is_none_or(|b| b > self.left) {
            return Err("truncated body".into());
        }
        let mut records = vec![T::new_zeroed(); count];
        self.read_exact(records.as_mut_bytes())?;
        Ok(records)
    }

    /// Checks that the whole body was read, that no more follows, and its checksum (a
    /// skimming reader: only that the caller's reads and skips came to the body's end).
    pub(crate) fn finish(mut self) -> Result<(), String> {
        if self.left != 0 {
            return Err("bytes after the body".into());
        }
        if self.file.is_some() {
            return Ok(());
        }
        let mut rest = [0u8; 1];
        let more = self
            .decoder
            .read(&mut rest)
            .map_err(|e| format!("damaged body ({e})"))?;
        if more != 0 {
            return Err("a body longer than its trailer states".into());
        }
        if self.hasher.digest() != self.checksum {
            return Err("truncated or damaged body (checksum mismatch)".into());
        }
        Ok(())
    }
}

/// The size of file `path`.
pub(crate) fn file_size(path: &Path) -> Result<u64, ShardError> {
    std::fs::metadata(path)
        .map(|m| m.len())
        .map_err(|source| ShardError::Io {
            path: path.to_path_buf(),
            source,
        })
}

/// The stored body of file `path` (whose ends [`read_ends`] read).
pub(crate) fn body_stream(path: &Path) -> Result<impl Read + use<>, ShardError> {
    let io = |source| ShardError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let size = file.metadata().map_err(io)?.len();
    file.seek(std::io::SeekFrom::Start(HEADER_BYTES))
        .map_err(io)?;
    // Buffered: the LZ4 decoder reads each block's 4-byte length before the block, and a
    // part's records are read a few bytes at a time.
    let body = file.take(size.saturating_sub(HEADER_BYTES + TRAILER_BYTES));
    Ok(std::io::BufReader::with_capacity(1 << 17, body))
}

/// A whole file in memory, for tests that damage bodies behind valid checksums.
#[cfg(test)]
pub(crate) fn encoded(magic: [u8; 8], index: u32, plan_id: u64, body: &[u8]) -> Vec<u8> {
    let mut file = Vec::new();
    file.extend_from_slice(&magic);
    file.extend_from_slice(&VERSION.to_le_bytes());
    file.extend_from_slice(&index.to_le_bytes());
    file.extend_from_slice(&plan_id.to_le_bytes());
    file.extend_from_slice(&xxh3_64(&file).to_le_bytes());
    match Codec::of(magic) {
        Codec::Lz4 => {
            let mut frame = encoder(Vec::new());
            frame.write_all(body).expect("in memory");
            file.extend(frame.finish().expect("in memory"));
        }
        Codec::Raw => file.extend_from_slice(body),
    }
    let mut trailer = Vec::new();
    trailer.extend_from_slice(&(body.len() as u64).to_le_bytes());
    trailer.extend_from_slice(&xxh3_64(body).to_le_bytes());
    trailer.extend_from_slice(&xxh3_64(&trailer).to_le_bytes());
    file.extend(trailer);
    file
}
