//! STL, binary and ASCII. STL stores three vertex positions per triangle and shares nothing,
//! so every triangle adds three vertices here and welding (in `weld`) joins them.
//!
//! Hand-written rather than through `stl_io`: the format is a 50-byte record or a handful of
//! keywords, and we need typed errors with byte and line positions and a triangle count that
//! is checked against the file size before anything is allocated.

use crate::error::{FormatError, Location, Problem};
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
    soup.positions.reserve(count as usize * 3);
    soup.triangles.reserve(count as usize);
    soup.triangle_parts.reserve(count as usize);
    for (index, record) in body
        .chunks_exact(RECORD_BYTES as usize)
        .take(count as usize)
        .enumerate()
    {
        // Bytes 0..12 are the facet normal, 48..50 the attribute word: neither is used.
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
    }
    Ok(())
}

fn read_ascii(data: &[u8], default_name: &str, soup: &mut MeshSoup) -> Result<(), FormatError> {
    let text = std::str::from_utf8(data).map_err(|e| {
        FormatError::syntax(
            Location::Byte(e.valid_up_to() as u64),
            "ASCII STL is not valid UTF-8",
        )
    })?;
    let mut part: Option<u32> = None;
    let mut solids = 0usize;
    let mut loop_corners: Vec<u32> = Vec::new();
    let mut in_loop = false;
    for (line_index, line) in text.lines().enumerate() {
        let line_number = line_index as u64 + 1;
        let at = || Location::Line(line_number);
        let mut words = line.split_whitespace();
        let Some(keyword) = words.next() else {
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
            }
            "facet" | "endfacet" | "endsolid" => {}
            other => {
                return Err(FormatError::syntax(
                    at(),
                    format!("unexpected keyword '{other}'"),
                ));
            }
        }
    }
    if in_loop {
        return Err(FormatError::syntax(
            Location::Line(text.lines().count() as u64),
            "file ends inside 'outer loop'",
        ));
    }
    Ok(())
}
