//! STL, binary and ASCII. STL stores three vertex positions per triangle and shares nothing,
//! so every triangle adds three vertices here and welding (in `weld`) joins them.
//!
//! Colour: binary STL has no standard for it, but two conventions use each facet's 16-bit
//! attribute word. The common one, VisCAM and SolidView's, is read by default: bit 15 set
//! means the facet has a colour, bits 10–14 red, 5–9 green, 0–4 blue (5 bits each). A file
//! whose 80-byte header holds `COLOR=` follows Materialise Magics instead: the four bytes
//! after it are the object's RGBA, and a facet with bit 15 *clear* has its own colour, red
//! in bits 0–4, green 5–9, blue 10–14. The part's colour is the average over its facets
//! that have one (the object colour standing in for the others under Magics); none if no
//! facet has one. ASCII STL has no colour.
//!
//! Hand-written rather than through `stl_io`: the format is a 50-byte record or a handful of
//! keywords, and we need typed errors with byte and line positions and a triangle count that
//! is checked against the file size before anything is allocated.

use crate::error::{FormatError, Location, Problem};
use crate::mapped::{FacetRows, FoundRows, RowLayout};
use crate::soup::MeshSoup;

const HEADER_BYTES: usize = 80;
const RECORD_BYTES: u64 = 50;

/// Reads an STL file's bytes into `soup`: one part for a binary file, one per `solid` for an
/// ASCII file.
pub fn read_stl(data: &[u8], default_name: &str, soup: &mut MeshSoup) -> Result<(), FormatError> {
    let binary_size = (data.len() >= HEADER_BYTES + 4).then(|| {
        let count = u32::from_le_bytes(data[80..84].try_into().expect("4 bytes"));
        (HEADER_BYTES as u64 + 4) + u64::from(count) * RECORD_BYTES
    });
    let looks_ascii = data
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .is_some_and(|start| data[start..].starts_with(b"solid"));
    // Binary files may also begin with "solid"; a size that matches the record count wins.
    if binary_size == Some(data.len() as u64) || !looks_ascii {
        read_binary(data, default_name, soup)
    } else {
        read_ascii(data, default_name, soup)
    }
}

fn read_binary(data: &[u8], name: &str, soup: &mut MeshSoup) -> Result<(), FormatError> {
    if data.len() < HEADER_BYTES + 4 {
        return Err(FormatError::new(
            Location::Byte(0),
            Problem::Truncated {
                needed: (HEADER_BYTES + 4) as u64,
                available: data.len() as u64,
            },
        ));
    }
    let count = u64::from(u32::from_le_bytes(
        data[80..84].try_into().expect("4 bytes"),
    ));
    let body = &data[HEADER_BYTES + 4..];
    let needed = count * RECORD_BYTES;
    if needed > body.len() as u64 {
        return Err(FormatError::new(
            Location::Byte((HEADER_BYTES + 4) as u64),
            Problem::Truncated {
                needed,
                available: body.len() as u64,
            },
        ));
    }
    let part = soup.begin_part(name);
    let convention = ColorConvention::of_header(&data[..HEADER_BYTES]);
    let mut color = crate::soup::ColorSum::default();
    soup.reserve(count as usize * 3, count as usize);
    for (index, record) in body
        .chunks_exact(RECORD_BYTES as usize)
        .take(count as usize)
        .enumerate()
    {
        // Bytes 0..12 are the facet normal (not used), 48..50 the attribute word.
        if let Some(rgba) = convention.facet(u16::from_le_bytes([record[48], record[49]])) {
            color.add(rgba);
        }
        let mut corners = [0u32; 3];
        for (k, corner) in corners.iter_mut().enumerate() {
            let at = 12 + 12 * k;
            let coord = |i: usize| {
                f32::from_le_bytes(
                    record[at + 4 * i..at + 4 * i + 4]
                        .try_into()
                        .expect("4 bytes"),
                )
            };
            *corner = soup.push_vertex([coord(0), coord(1), coord(2)], || Location::Element {
                kind: "triangle".into(),
                index: index as u64,
            })?;
        }
        soup.push_polygon(part, &corners);
        let read = index + 1;
        if soup.spills() && (read % soup.spill_rows() == 0 || read as u64 == count) {
            // Every facet of the piece made three vertices and one triangle: a spilling
            // soup reads them again from the map ([`crate::mapped`]).
            let first = read - soup.triangles.len();
            let piece = &body[first * RECORD_BYTES as usize..read * RECORD_BYTES as usize];
            soup.spill_found(Some(FoundRows {
                address: piece.as_ptr() as usize,
                bytes: piece.len(),
                first_row: first as u64,
                stride: RECORD_BYTES as usize,
                layout: RowLayout::Facets(FacetRows {
                    part,
                    vertex_base: 0,
                    part_base: 0,
                }),
            }));
            soup.done_with_input(&data[..HEADER_BYTES + 4 + read * RECORD_BYTES as usize]);
        }
    }
    soup.parts[part as usize].color = color.mean();
    Ok(())
}

/// How a binary STL stores facet colours in the attribute word (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
enum ColorConvention {
    /// VisCAM / SolidView: bit 15 set means valid, red in the high bits.
    VisCam,
    /// Materialise Magics: bit 15 clear means the facet's own colour, red in the low bits;
    /// the header's `COLOR=` RGBA otherwise.
    Magics { object: [f64; 4] },
}

impl ColorConvention {
    fn of_header(header: &[u8]) -> ColorConvention {
        const KEY: &[u8] = b"COLOR=";
        match header.windows(KEY.len()).position(|w| w == KEY) {
            Some(at) if at + KEY.len() + 4 <= header.len() => {
                let b = &header[at + KEY.len()..at + KEY.len() + 4];
                ColorConvention::Magics {
                    object: [0, 1, 2, 3].map(|k| f64::from(b[k]) / 255.0),
                }
            }
            _ => ColorConvention::VisCam,
        }
    }

    /// The colour a facet's attribute word gives it, if any.
    fn facet(self, word: u16) -> Option<[f64; 4]> {
        let five = |shift: u16| f64::from((word >> shift) & 31) / 31.0;
        let valid = word & 0x8000 != 0;
        match self {
            ColorConvention::VisCam => valid.then(|| [five(10), five(5), five(0), 1.0]),
            ColorConvention::Magics { object } if valid => Some(object),
            ColorConvention::Magics { .. } => Some([five(0), five(5), five(10), 1.0]),
        }
    }
}

/// Reads an ASCII STL a line at a time (each checked as UTF-8 on its own, so that the input
/// is read once, front to back). A soup that spills takes every [`MeshSoup::spill_rows`]
/// facets, and the text read is let go of as the reader goes.
fn read_ascii(data: &[u8], default_name: &str, soup: &mut MeshSoup) -> Result<(), FormatError> {
    let mut part: Option<u32> = None;
    let mut solids = 0usize;
    let mut loop_corners: Vec<u32> = Vec::new();
    let mut in_loop = false;
    let mut facets = 0usize;
    let mut line_number = 0u64;
    let mut start = 0usize;
    let mut released = 0usize;
    while start < data.len() {
        // The text read is let go of a megabyte at a time, as OBJ text is: a facet is about
        // 190 bytes of text, so the rows between spills would hold 50 MB of it.
        if soup.spills() && start - released >= crate::obj::CHUNK_BYTES {
            soup.done_with_input(&data[..start]);
            released = start;
        }
        let end = memchr::memchr(b'\n', &data[start..]).map_or(data.len(), |at| start + at);
        let next = (end + 1).min(data.len());
        // A line's `\r` before its `\n` is whitespace to the words below.
        let line = std::str::from_utf8(&data[start..end]).map_err(|e| {
            FormatError::syntax(
                Location::Byte((start + e.valid_up_to()) as u64),
                "ASCII STL is not valid UTF-8",
            )
        })?;
        line_number += 1;
        let at = || Location::Line(line_number);
        let mut words = line.split_whitespace();
        let Some(keyword) = words.next() else {
            start = next;
            continue;
        };
        match keyword {
            "solid" => {
                let name: Vec<&str> = words.collect();
                let name = if name.is_empty() {
                    if solids == 0 {
                        default_name.to_string()
                    } else {
                        format!("{default_name}#{solids}")
                    }
                } else {
                    name.join(" ")
                };
                solids += 1;
                part = Some(soup.begin_part(name));
            }
            "outer" => {
                if in_loop {
                    return Err(FormatError::syntax(at(), "'outer loop' inside a loop"));
                }
                in_loop = true;
                loop_corners.clear();
            }
            "vertex" => {
                if !in_loop {
                    return Err(FormatError::syntax(at(), "'vertex' outside 'outer loop'"));
                }
                let mut p = [0f32; 3];
                for c in &mut p {
                    *c = words
                        .next()
                        .and_then(|w| w.parse().ok())
                        .ok_or_else(|| FormatError::syntax(at(), "'vertex' needs three numbers"))?;
                }
                loop_corners.push(soup.push_vertex(p, at)?);
            }
            "endloop" => {
                if !in_loop {
                    return Err(FormatError::syntax(at(), "'endloop' without 'outer loop'"));
                }
                in_loop = false;
                let part = match part {
                    Some(part) => part,
                    None => *part.insert(soup.begin_part(default_name)),
                };
                soup.push_polygon(part, &loop_corners);
                facets += 1;
                if soup.spills() && facets.is_multiple_of(soup.spill_rows()) {
                    soup.spill_now();
                }
            }
            "facet" | "endfacet" | "endsolid" => {}
            other => {
                return Err(FormatError::syntax(
                    at(),
                    format!("unexpected keyword '{other}'"),
                ));
            }
        }
        start = next;
    }
    if in_loop {
        return Err(FormatError::syntax(
            Location::Line(line_number),
            "file ends inside 'outer loop'",
        ));
    }
    Ok(())
}
