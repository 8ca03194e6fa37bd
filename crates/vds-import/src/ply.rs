//! Stanford PLY: ASCII, binary little-endian and binary big-endian, any property layout
//! (extra properties such as normals and flags are skipped), polygon faces.
//!
//! Colour: scalar `red`, `green`, `blue` (and `alpha`; also `diffuse_red` ...) of the faces,
//! else of the vertices, scaled to `0..=1` (integers by their type's largest value, floats
//! as they are) and averaged per part over its triangles (a triangle's colour is its face's,
//! or the mean of its corners').
//!
//! Hand-written: the PLY crates on crates.io (`ply-rs`) are unmaintained and allocate from
//! header counts without checking them against the file. This reader checks every count
//! against the bytes that remain before it reserves memory, and names the element and row of
//! any bad value.

use crate::error::{FormatError, Location, Problem};
use crate::soup::{MeshSoup, check_index};

/// Headers longer than this are rejected: real headers are a few hundred bytes, and the limit
/// keeps a file without `end_header` from being scanned as one.
const MAX_HEADER_BYTES: usize = 1 << 20;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

impl Scalar {
    /// A colour component of this type scaled to `0..=1` (clamped; integers by their
    /// type's largest value, floats as they are).
    fn unit(self, value: f64) -> f64 {
        let largest = match self {
            Scalar::I8 => f64::from(i8::MAX),
            Scalar::U8 => f64::from(u8::MAX),
            Scalar::I16 => f64::from(i16::MAX),
            Scalar::U16 => f64::from(u16::MAX),
            Scalar::I32 => f64::from(i32::MAX),
            Scalar::U32 => f64::from(u32::MAX),
            Scalar::F32 | Scalar::F64 => 1.0,
        };
        (value / largest).clamp(0.0, 1.0)
    }
}

/// Which colour channel (red, green, blue, alpha) a property name is.
fn color_channel(name: &str) -> Option<usize> {
    match name.strip_prefix("diffuse_").unwrap_or(name) {
        "red" => Some(0),
        "green" => Some(1),
        "blue" => Some(2),
        "alpha" => Some(3),
        _ => None,
    }
}

/// The property slots of an element's colour channels, when it has red, green and blue
/// scalars (alpha optional).
fn color_slots(element: &Element) -> Option<[Option<usize>; 4]> {
    let mut slots = [None; 4];
    for (index, property) in element.properties.iter().enumerate() {
        if let Property::Scalar { name, .. } = property
            && let Some(channel) = color_channel(name)
        {
            slots[channel].get_or_insert(index);
        }
    }
    slots[..3].iter().all(Option::is_some).then_some(slots)
}

/// A row's colour from the values of its colour slots (alpha 1 when there is none).
fn row_color(values: &[f64; 4], slots: &[Option<usize>; 4]) -> [f32; 4] {
    let mut rgba = [1f32; 4];
    for k in 0..4 {
        if slots[k].is_some() {
            rgba[k] = values[k] as f32;
        }
    }
    rgba
}

#[derive(Debug, Clone)]
enum Property {
    Scalar {
        name: String,
        ty: Scalar,
    },
    List {
        name: String,
        count: Scalar,
        item: Scalar,
    },
}

impl Property {
    fn name(&self) -> &str {
        match self {
            Property::Scalar { name, .. } | Property::List { name, .. } => name,
        }
    }

    /// The fewest bytes (binary) a value of this property can take.
    fn min_binary_bytes(&self) -> usize {
        match self {
            Property::Scalar { ty, .. } => ty.size(),
            Property::List { count, .. } => count.size(),
        }
    }
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: u64,
    properties: Vec<Property>,
    header_line: u64,
}

struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    body_start: usize,
}

fn parse_header(data: &[u8]) -> Result<Header, FormatError> {
    let limit = data.len().min(MAX_HEADER_BYTES);
    let mut lines = data[..limit].split_inclusive(|&b| b == b'\n');
    let mut offset = 0usize;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line_number = 0u64;
    let mut next_line = |offset: &mut usize, line_number: &mut u64| {
        let raw = lines.next()?;
        *offset += raw.len();
        *line_number += 1;
        Some(String::from_utf8_lossy(raw).trim().to_string())
    };
    match next_line(&mut offset, &mut line_number) {
        Some(magic) if magic == "ply" => {}
        _ => {
            return Err(FormatError::syntax(
                Location::Line(1),
                "missing 'ply' magic line",
            ));
        }
    }
    loop {
        let Some(line) = next_line(&mut offset, &mut line_number) else {
            return Err(FormatError::syntax(
                Location::Line(line_number),
                "header has no 'end_header' line",
            ));
        };
        let at = Location::Line(line_number);
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["end_header"] => break,
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", kind, _version] => {
                encoding = Some(match *kind {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::BinaryLittleEndian,
                    "binary_big_endian" => Encoding::BinaryBigEndian,
                    other => {
                        return Err(FormatError::syntax(at, format!("unknown format '{other}'")));
                    }
                });
            }
            ["element", name, count] => {
                let count = count.parse::<u64>().map_err(|_| {
                    FormatError::syntax(at.clone(), format!("bad element count '{count}'"))
                })?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    properties: Vec::new(),
                    header_line: line_number,
                });
            }
            ["property", "list", count, item, name] => {
                let (Some(count), Some(item)) = (Scalar::parse(count), Scalar::parse(item)) else {
                    return Err(FormatError::syntax(at, format!("unknown type in '{line}'")));
                };
                if !count.is_integer() {
                    return Err(FormatError::syntax(
                        at,
                        "list count type must be an integer",
                    ));
                }
                let element = elements
                    .last_mut()
                    .ok_or_else(|| FormatError::syntax(at, "property before any element"))?;
                element.properties.push(Property::List {
                    name: name.to_string(),
                    count,
                    item,
                });
            }
            ["property", ty, name] => {
                let ty = Scalar::parse(ty).ok_or_else(|| {
                    FormatError::syntax(at.clone(), format!("unknown type '{ty}'"))
                })?;
                let element = elements
                    .last_mut()
                    .ok_or_else(|| FormatError::syntax(at, "property before any element"))?;
                element.properties.push(Property::Scalar {
                    name: name.to_string(),
                    ty,
                });
            }
            _ => {
                return Err(FormatError::syntax(
                    at,
                    format!("unexpected header line '{line}'"),
                ));
            }
        }
    }
    let encoding = encoding
        .ok_or_else(|| FormatError::syntax(Location::Line(1), "header has no 'format' line"))?;
    Ok(Header {
        encoding,
        elements,
        body_start: offset,
    })
}

/// Reads values of the body one at a time, in either encoding.
trait Values {
    /// Reads a value of type `ty` as a float.
    fn real(&mut self, ty: Scalar) -> Result<f64, FormatError>;
    /// Reads a value of integer type `ty`.
    fn integer(&mut self, ty: Scalar) -> Result<i64, FormatError>;
    /// Bytes not yet read.
    fn remaining(&self) -> usize;
    /// Where the next value starts.
    fn location(&self) -> Location;
    /// The unread bytes and their byte order, for binary bodies (the fixed-row fast paths).
    fn raw(&self) -> Option<(&[u8], bool)> {
        None
    }
    /// Skips `n` bytes that a fast path consumed.
    fn skip_bytes(&mut self, _n: usize) {}
    /// The bytes read so far.
    fn consumed(&self) -> &[u8];
}

struct Binary<'a> {
    data: &'a [u8],
    position: usize,
    big_endian: bool,
}

impl Binary<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], FormatError> {
        let bytes = self
            .data
            .get(self.position..self.position + N)
            .ok_or_else(|| {
                FormatError::new(
                    Location::Byte(self.position as u64),
                    Problem::Truncated {
                        needed: N as u64,
                        available: (self.data.len() - self.position) as u64,
                    },
                )
            })?;
        self.position += N;
        let mut out: [u8; N] = bytes.try_into().expect("slice of N bytes");
        if self.big_endian {
            out.reverse();
        }
        Ok(out)
    }
}

impl Values for Binary<'_> {
    fn raw(&self) -> Option<(&[u8], bool)> {
        Some((&self.data[self.position..], self.big_endian))
    }

    fn skip_bytes(&mut self, n: usize) {
        self.position += n;
    }

    fn real(&mut self, ty: Scalar) -> Result<f64, FormatError> {
        Ok(match ty {
            Scalar::F32 => f64::from(f32::from_le_bytes(self.take()?)),
            Scalar::F64 => f64::from_le_bytes(self.take()?),
            _ => self.integer(ty)? as f64,
        })
    }

    fn integer(&mut self, ty: Scalar) -> Result<i64, FormatError> {
        Ok(match ty {
            Scalar::I8 => i64::from(i8::from_le_bytes(self.take()?)),
            Scalar::U8 => i64::from(u8::from_le_bytes(self.take()?)),
            Scalar::I16 => i64::from(i16::from_le_bytes(self.take()?)),
            Scalar::U16 => i64::from(u16::from_le_bytes(self.take()?)),
            Scalar::I32 => i64::from(i32::from_le_bytes(self.take()?)),
            Scalar::U32 => i64::from(u32::from_le_bytes(self.take()?)),
            Scalar::F32 | Scalar::F64 => {
                return Err(FormatError::syntax(
                    self.location(),
                    "expected an integer type",
                ));
            }
        })
    }

    fn remaining(&self) -> usize {
        self.data.len() - self.position
    }

    fn location(&self) -> Location {
        Location::Byte(self.position as u64)
    }

    fn consumed(&self) -> &[u8] {
        &self.data[..self.position]
    }
}

struct Ascii<'a> {
    data: &'a [u8],
    position: usize,
    line: u64,
}

impl<'a> Ascii<'a> {
    fn token(&mut self) -> Result<&'a str, FormatError> {
        while let Some(&b) = self.data.get(self.position) {
            if !b.is_ascii_whitespace() {
                break;
            }
            if b == b'\n' {
                self.line += 1;
            }
            self.position += 1;
        }
        let start = self.position;
        while self
            .data
            .get(self.position)
            .is_some_and(|b| !b.is_ascii_whitespace())
        {
            self.position += 1;
        }
        if start == self.position {
            return Err(FormatError::new(
                Location::Line(self.line),
                Problem::Truncated {
                    needed: 1,
                    available: 0,
                },
            ));
        }
        std::str::from_utf8(&self.data[start..self.position])
            .map_err(|_| FormatError::syntax(Location::Line(self.line), "value is not ASCII"))
    }
}

impl Values for Ascii<'_> {
    fn real(&mut self, _ty: Scalar) -> Result<f64, FormatError> {
        let token = self.token()?;
        token.parse().map_err(|_| {
            FormatError::syntax(Location::Line(self.line), format!("bad number '{token}'"))
        })
    }

    fn integer(&mut self, _ty: Scalar) -> Result<i64, FormatError> {
        let token = self.token()?;
        token.parse().map_err(|_| {
            FormatError::syntax(Location::Line(self.line), format!("bad integer '{token}'"))
        })
    }

    fn remaining(&self) -> usize {
        self.data.len() - self.position
    }

    fn location(&self) -> Location {
        Location::Line(self.line)
    }

    fn consumed(&self) -> &[u8] {
        &self.data[..self.position]
    }
}

/// Reads a PLY file's bytes into `soup` as one part named `name`.
pub fn read_ply(data: &[u8], name: &str, soup: &mut MeshSoup) -> Result<(), FormatError> {
    let header = parse_header(data)?;
    let body = &data[header.body_start..];
    match header.encoding {
        Encoding::Ascii => {
            let header_lines = data[..header.body_start]
                .iter()
                .filter(|&&b| b == b'\n')
                .count();
            let mut values = Ascii {
                data: body,
                position: 0,
                line: header_lines as u64 + 1,
            };
            read_body(&header, &mut values, true, name, soup)
        }
        encoding => {
            let mut values = Binary {
                data: body,
                position: 0,
                big_endian: encoding == Encoding::BinaryBigEndian,
            };
            read_body(&header, &mut values, false, name, soup)
        }
    }
}

/// Reads every element in header order. For `ascii` bodies a value takes at least two bytes
/// (a digit and a separator), which bounds how many rows the remaining bytes can hold.
fn read_body(
    header: &Header,
    values: &mut impl Values,
    ascii: bool,
    name: &str,
    soup: &mut MeshSoup,
) -> Result<(), FormatError> {
    let vertex_count = header
        .elements
        .iter()
        .find(|e| e.name == "vertex")
        .map_or(0, |e| e.count);
    let base = soup.vertex_count();
    let part = soup.begin_part(name);
    let mut colors = PartColors::new(part);
    let mut saw_faces = false;
    // This file's vertex colours, and one colour per triangle when the faces have them.
    let mut vertex_colors: Vec<[f32; 4]> = Vec::new();
    let mut triangle_colors: Vec<[f32; 4]> = Vec::new();
    for element in &header.elements {
        let min_row_bytes: usize = element
            .properties
            .iter()
            .map(|p| if ascii { 2 } else { p.min_binary_bytes() })
            .sum();
        if min_row_bytes == 0 {
            continue; // An element without properties occupies no bytes.
        }
        let max_possible = (values.remaining() / min_row_bytes) as u64;
        if element.count > max_possible {
            return Err(FormatError::new(
                Location::Line(element.header_line),
                Problem::CountExceedsFile {
                    what: format!("element '{}'", element.name),
                    count: element.count,
                    max_possible,
                },
            ));
        }
        match element.name.as_str() {
            "vertex" => {
                for piece in pieces(element, soup) {
                    let (rows, first) = (&piece.element, piece.first_row);
                    let mut found = None;
                    if !fast::read_vertices(
                        rows,
                        first,
                        values,
                        soup,
                        &mut vertex_colors,
                        &mut found,
                    )? {
                        read_vertices(rows, first, values, soup, &mut vertex_colors)?;
                    }
                    soup.spill_found(found);
                    soup.done_with_input(values.consumed());
                }
            }
            "face" => {
                saw_faces = true;
                let mut parts = PartMap::new(name, part);
                for piece in pieces(element, soup) {
                    let first_triangle = soup.triangles.len();
                    let mut faces = Faces {
                        vertex_count,
                        base,
                        parts: &mut parts,
                        soup,
                        triangle_colors: &mut triangle_colors,
                    };
                    let mut found = None;
                    if !fast::read_faces(&piece, values, &mut faces, &mut found)? {
                        read_faces(&piece, values, &mut faces)?;
                    }
                    // The file's vertices are all read when its faces are (PLY puts the
                    // vertex element first in practice); faces before them get no colour.
                    let file_vertices = soup.vertex_count() - base;
                    colors.add(
                        soup,
                        first_triangle,
                        base,
                        (vertex_colors.len() == file_vertices).then_some(&vertex_colors[..]),
                        &triangle_colors,
                    );
                    triangle_colors.clear();
                    soup.spill_found(found);
                    soup.done_with_input(values.consumed());
                }
                parts.publish();
            }
            _ => skip_rows(element, values)?,
        }
    }
    if !saw_faces && header.elements.iter().any(|e| e.name == "tristrips") {
        return Err(FormatError::new(
            Location::File,
            Problem::Unsupported("PLY 'tristrips' element without 'face'".into()),
        ));
    }
    colors.finish(soup);
    Ok(())
}

/// Rows of an element read at once: the element's first `element.count` rows from `first_row`.
struct Piece {
    element: Element,
    first_row: u64,
}

/// An element read in pieces of at most [`crate::SPILL_ROWS`] rows when the soup spills; else
/// the element whole.
fn pieces(element: &Element, soup: &MeshSoup) -> Vec<Piece> {
    let rows = if soup.spills() {
        soup.spill_rows() as u64
    } else {
        element.count.max(1)
    };
    (0..element.count.div_ceil(rows).max(1))
        .map(|k| {
            let first = k * rows;
            Piece {
                element: Element {
                    count: (element.count - first).min(rows),
                    ..element.clone()
                },
                first_row: first,
            }
        })
        .collect()
}

/// The colours of a file's parts: each triangle's colour is its face's when the faces have
/// colours, else the mean of its corners' when the vertices have, averaged per part over its
/// triangles. Triangles are added a piece at a time, as they are read.
struct PartColors {
    first_part: u32,
    sums: Vec<crate::soup::ColorSum>,
}

impl PartColors {
    fn new(first_part: u32) -> PartColors {
        PartColors {
            first_part,
            sums: Vec::new(),
        }
    }

    /// Adds the soup's triangles from `first_triangle` (in memory) with their faces' colours
    /// (`triangle_colors`, one per triangle, or none) or their corners' (`vertex_colors`,
    /// indexed from `base`, one per vertex of the file).
    fn add(
        &mut self,
        soup: &MeshSoup,
        first_triangle: usize,
        base: usize,
        vertex_colors: Option<&[[f32; 4]]>,
        triangle_colors: &[[f32; 4]],
    ) {
        let triangles = &soup.triangles[first_triangle..];
        let parts = &soup.triangle_parts[first_triangle..];
        let by_face = !triangle_colors.is_empty() && triangle_colors.len() == triangles.len();
        if !by_face && vertex_colors.is_none_or(|c| c.is_empty()) {
            return; // No colours, or not one per vertex and per triangle.
        }
        let parts_now = soup.part_names.len() - self.first_part as usize;
        self.sums.resize(parts_now, Default::default());
        for (t, (corners, &part)) in triangles.iter().zip(parts).enumerate() {
            let rgba = match vertex_colors {
                _ if by_face => triangle_colors[t].map(f64::from),
                Some(vertex_colors) => {
                    let mut mean = [0f64; 4];
                    for &corner in corners {
                        let c = vertex_colors[corner as usize - base];
                        for k in 0..4 {
                            mean[k] += f64::from(c[k]) / 3.0;
                        }
                    }
                    mean
                }
                None => unreachable!("checked above"),
            };
            self.sums[(part - self.first_part) as usize].add(rgba);
        }
    }

    /// Sets the parts' colours.
    fn finish(self, soup: &mut MeshSoup) {
        for (k, sum) in self.sums.iter().enumerate() {
            soup.parts[self.first_part as usize + k].color = sum.mean();
        }
    }
}

fn read_vertices(
    element: &Element,
    first_row: u64,
    values: &mut impl Values,
    soup: &mut MeshSoup,
    colors: &mut Vec<[f32; 4]>,
) -> Result<(), FormatError> {
    let color_slots = color_slots(element);
    let axis = |axis: &str| {
        element
            .properties
            .iter()
            .position(|p| matches!(p, Property::Scalar { name, .. } if name == axis))
            .ok_or_else(|| {
                FormatError::syntax(
                    Location::Line(element.header_line),
                    format!("vertex element has no scalar property '{axis}'"),
                )
            })
    };
    let slots = [axis("x")?, axis("y")?, axis("z")?];
    soup.reserve(element.count as usize, 0);
    if color_slots.is_some() {
        colors.reserve(element.count as usize);
    }
    for row in 0..element.count {
        let mut p = [0f32; 3];
        let mut color = [0f64; 4];
        for (index, property) in element.properties.iter().enumerate() {
            match property {
                Property::Scalar { ty, .. } => {
                    let value = values.real(*ty)?;
                    if let Some(axis) = slots.iter().position(|&s| s == index) {
                        p[axis] = value as f32;
                    }
                    if let Some(channel) =
                        color_slots.and_then(|c| c.iter().position(|&s| s == Some(index)))
                    {
                        color[channel] = ty.unit(value);
                    }
                }
                Property::List { count, item, .. } => skip_list(values, *count, *item)?,
            }
        }
        if let Some(slots) = &color_slots {
            colors.push(row_color(&color, slots));
        }
        soup.push_vertex(p, || Location::Element {
            kind: "vertex".into(),
            index: first_row + row,
        })?;
    }
    Ok(())
}

/// Part ids from an optional per-face `part` property: each distinct value becomes a part,
/// in order of first appearance; without the property every face is in the file's part.
struct PartMap {
    file_name: String,
    file_part: u32,
    by_value: rustc_hash::FxHashMap<i64, u32>,
    /// Each value's part, once every face is read: what faces read again from the map
    /// ([`crate::mapped`]) look their parts up in.
    table: std::sync::Arc<std::sync::OnceLock<rustc_hash::FxHashMap<u32, u32>>>,
}

impl PartMap {
    fn new(file_name: &str, file_part: u32) -> PartMap {
        PartMap {
            file_name: file_name.to_string(),
            file_part,
            by_value: Default::default(),
            table: Default::default(),
        }
    }

    /// Publishes the parts of every value seen (those that fit a `u32`: the only ones the
    /// faces read again from the map hold) for the faces read again from the map.
    fn publish(&self) {
        let table = self
            .by_value
            .iter()
            .filter_map(|(&value, &part)| Some((u32::try_from(value).ok()?, part)))
            .collect();
        // The map's only `set`: each face element has a map of its own.
        let _ = self.table.set(table);
    }

    fn part(&mut self, value: Option<i64>, soup: &mut MeshSoup) -> u32 {
        let Some(value) = value else {
            return self.file_part;
        };
        if let Some(&part) = self.by_value.get(&value) {
            return part;
        }
        let part = if self.by_value.is_empty() {
            // The first value takes over the file's (so far empty) part.
            soup.part_names[self.file_part as usize] = format!("{} part {value}", self.file_name);
            self.file_part
        } else {
            soup.begin_part(format!("{} part {value}", self.file_name))
        };
        self.by_value.insert(value, part);
        part
    }
}

/// The slot of the optional integer `part` property of a face element.
fn part_slot(element: &Element) -> Option<usize> {
    element.properties.iter().position(
        |p| matches!(p, Property::Scalar { name, ty } if name == "part" && ty.is_integer()),
    )
}

/// Where a face element's rows go, for both face readers: the file's vertex count and first
/// vertex, its parts, the soup, and one colour per triangle when the faces have colours.
struct Faces<'a> {
    vertex_count: u64,
    base: usize,
    parts: &'a mut PartMap,
    soup: &'a mut MeshSoup,
    triangle_colors: &'a mut Vec<[f32; 4]>,
}

fn read_faces(
    piece: &Piece,
    values: &mut impl Values,
    faces: &mut Faces,
) -> Result<(), FormatError> {
    let (vertex_count, base) = (faces.vertex_count, faces.base);
    let (element, first_row) = (&piece.element, piece.first_row);
    let part_slot = part_slot(element);
    let color_slots = color_slots(element);
    let corners_slot = element
        .properties
        .iter()
        .position(|p| {
            matches!(p, Property::List { .. })
                && (p.name() == "vertex_indices" || p.name() == "vertex_index")
        })
        .ok_or_else(|| {
            FormatError::syntax(
                Location::Line(element.header_line),
                "face element has no list property 'vertex_indices'",
            )
        })?;
    faces.soup.reserve(0, element.count as usize);
    let mut corners: Vec<u32> = Vec::new();
    for row in 0..element.count {
        let mut part_value = None;
        let mut color = [0f64; 4];
        for (index, property) in element.properties.iter().enumerate() {
            match property {
                Property::List { count, item, .. } if index == corners_slot => {
                    let at = values.location();
                    let n = values.integer(*count)?;
                    if n < 0 || n as usize > values.remaining() {
                        return Err(FormatError::new(
                            at,
                            Problem::CountExceedsFile {
                                what: format!("corner list of face {}", first_row + row),
                                count: n as u64,
                                max_possible: values.remaining() as u64,
                            },
                        ));
                    }
                    corners.clear();
                    for _ in 0..n {
                        let index = values.integer(*item).map_err(|e| match e.problem {
                            Problem::Syntax(_) => FormatError::syntax(
                                e.location,
                                "face vertex indices must have an integer type",
                            ),
                            _ => e,
                        })?;
                        let vertex =
                            check_index(index, vertex_count as usize, || Location::Element {
                                kind: "face".into(),
                                index: first_row + row,
                            })?;
                        corners.push(base as u32 + vertex);
                    }
                }
                Property::List { count, item, .. } => skip_list(values, *count, *item)?,
                Property::Scalar { ty, .. } if Some(index) == part_slot => {
                    part_value = Some(values.integer(*ty)?);
                }
                Property::Scalar { ty, .. } => {
                    let value = values.real(*ty)?;
                    if let Some(channel) =
                        color_slots.and_then(|c| c.iter().position(|&s| s == Some(index)))
                    {
                        color[channel] = ty.unit(value);
                    }
                }
            }
        }
        let part = faces.parts.part(part_value, faces.soup);
        let before = faces.soup.triangles.len();
        faces.soup.push_polygon(part, &corners);
        if let Some(slots) = &color_slots {
            let rgba = row_color(&color, slots);
            faces.triangle_colors.extend(std::iter::repeat_n(
                rgba,
                faces.soup.triangles.len() - before,
            ));
        }
    }
    Ok(())
}

fn skip_list(values: &mut impl Values, count: Scalar, item: Scalar) -> Result<(), FormatError> {
    let at = values.location();
    let n = values.integer(count)?;
    if n < 0 || n as usize > values.remaining() {
        return Err(FormatError::new(
            at,
            Problem::CountExceedsFile {
                what: "list".into(),
                count: n as u64,
                max_possible: values.remaining() as u64,
            },
        ));
    }
    for _ in 0..n {
        values.real(item)?;
    }
    Ok(())
}

fn skip_rows(element: &Element, values: &mut impl Values) -> Result<(), FormatError> {
    for _ in 0..element.count {
        for property in &element.properties {
            match property {
                Property::Scalar { ty, .. } => {
                    values.real(*ty)?;
                }
                Property::List { count, item, .. } => skip_list(values, *count, *item)?,
            }
        }
    }
    Ok(())
}

/// Fast paths for binary files whose rows have a fixed size: every vertex property a scalar,
/// and every face a triangle. They decode rows in parallel straight from the bytes, and
/// return `Ok(false)` without consuming anything when the layout does not qualify, so the
/// general reader above handles (and reports on) everything else.
mod fast {
    use rayon::prelude::*;

    use super::{
        Element, Faces, Piece, Property, Scalar, Values, color_slots, part_slot, row_color,
    };
    use crate::error::FormatError;
    use crate::mapped::{FaceParts, FaceRows, FoundRows, RowLayout};
    use crate::soup::{MeshSoup, check_position};

    /// Rows decoded per parallel task.
    const ROWS_PER_TASK: usize = 1 << 14;

    fn scalar(bytes: &[u8], ty: Scalar, big_endian: bool) -> f64 {
        let mut b = [0u8; 8];
        let n = ty.size();
        b[..n].copy_from_slice(&bytes[..n]);
        if big_endian {
            b[..n].reverse();
        }
        match ty {
            Scalar::I8 => f64::from(b[0] as i8),
            Scalar::U8 => f64::from(b[0]),
            Scalar::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            Scalar::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            Scalar::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::F64 => f64::from_le_bytes(b),
        }
    }

    fn integer(bytes: &[u8], ty: Scalar, big_endian: bool) -> i64 {
        // Integer types up to 32 bits are exact in f64.
        scalar(bytes, ty, big_endian) as i64
    }

    /// The first four bytes of `bytes`.
    ///
    /// The layouts nearly every binary PLY file uses (little-endian `float` coordinates,
    /// `uchar` counts with `int`/`uint` indices, a `uint` part) are read by closures over
    /// this instead of the generic [`scalar`], which dispatches on the type of every value:
    /// that dispatch was 90 % of the instructions of parsing a 1 M-triangle scene.
    fn four(bytes: &[u8]) -> [u8; 4] {
        bytes[..4].try_into().expect("4 bytes")
    }

    /// Decodes one position from each fixed-size row with `read`.
    fn positions(
        raw: &[u8],
        stride: usize,
        read: impl Fn(&[u8]) -> [f32; 3] + Sync,
    ) -> Vec<[f32; 3]> {
        raw.par_chunks_exact(stride).map(&read).collect()
    }

    /// One colour per fixed-size row of `raw`, when the element has colour slots.
    fn row_colors(
        element: &Element,
        raw: &[u8],
        stride: usize,
        big_endian: bool,
    ) -> Option<Vec<[f32; 4]>> {
        let slots = color_slots(element)?;
        // Byte offsets and types of the colour properties (every property before them is a
        // scalar or a triangle list of this layout, whose sizes the caller summed the same way).
        let mut at = Vec::new();
        let mut offset = 0;
        for (index, property) in element.properties.iter().enumerate() {
            match property {
                Property::Scalar { ty, .. } => {
                    if let Some(channel) = slots.iter().position(|&s| s == Some(index)) {
                        at.push((channel, offset, *ty));
                    }
                    offset += ty.size();
                }
                Property::List { count, item, .. } => offset += count.size() + 3 * item.size(),
            }
        }
        Some(
            raw.par_chunks_exact(stride)
                .map(|row| {
                    let mut color = [0f64; 4];
                    for &(channel, offset, ty) in &at {
                        color[channel] = ty.unit(scalar(&row[offset..], ty, big_endian));
                    }
                    row_color(&color, &slots)
                })
                .collect(),
        )
    }

    pub(super) fn read_vertices(
        element: &Element,
        first_row: u64,
        values: &mut impl Values,
        soup: &mut MeshSoup,
        colors: &mut Vec<[f32; 4]>,
        found: &mut Option<FoundRows>,
    ) -> Result<bool, FormatError> {
        let Some((raw, big_endian)) = values.raw() else {
            return Ok(false);
        };
        let mut offsets = [None; 3];
        let mut stride = 0;
        for property in &element.properties {
            let Property::Scalar { name, ty } = property else {
                return Ok(false);
            };
            if let Some(axis) = ["x", "y", "z"].iter().position(|a| a == name) {
                offsets[axis] = Some((stride, *ty));
            }
            stride += ty.size();
        }
        let (Some(x), Some(y), Some(z)) = (offsets[0], offsets[1], offsets[2]) else {
            return Ok(false);
        };
        let bytes = element.count as usize * stride;
        if stride == 0 || bytes > raw.len() {
            return Ok(false);
        }
        let raw = &raw[..bytes];
        let little_f32 = [x.1, y.1, z.1] == [Scalar::F32; 3] && !big_endian;
        let positions = if little_f32 {
            let offsets = [x.0, y.0, z.0];
            positions(raw, stride, |row| {
                offsets.map(|at| f32::from_le_bytes(four(&row[at..])))
            })
        } else {
            positions(raw, stride, |row| {
                [x, y, z].map(|(at, ty)| scalar(&row[at..], ty, big_endian) as f32)
            })
        };
        if let Some((bad, problem)) = positions
            .iter()
            .enumerate()
            .find_map(|(i, &p)| check_position(p).err().map(|e| (i, e)))
        {
            return Err(FormatError::at_element(
                "vertex",
                first_row + bad as u64,
                problem,
            ));
        }
        if u32::try_from(soup.vertex_count() + positions.len()).is_err() {
            return Ok(false); // The general path reports the overflow.
        }
        if soup.positions.is_empty() {
            soup.positions = positions;
        } else {
            soup.positions.extend(positions);
        }
        if let Some(found) = row_colors(element, raw, stride, big_endian) {
            colors.extend(found);
        }
        // The layout the map's rows are read again in ([`crate::mapped`]).
        if little_f32 {
            *found = Some(FoundRows {
                address: raw.as_ptr() as usize,
                bytes,
                first_row,
                stride,
                layout: RowLayout::Positions {
                    at: [x.0, y.0, z.0],
                },
            });
        }
        values.skip_bytes(bytes);
        Ok(true)
    }

    /// Why a chunk of faces could not be decoded on the fast path.
    enum Stop {
        NotTriangle,
        BadIndex,
        BadPart,
    }

    /// Where the fields of a fixed-size face row are.
    struct FaceLayout {
        stride: usize,
        list_at: usize,
        count_size: usize,
        item_size: usize,
        /// Offset of the part property, if the faces have one.
        part_at: Option<usize>,
        vertex_count: u64,
        base: u32,
    }

    impl FaceLayout {
        /// Decodes the rows of `raw` in parallel into `triangles` and raw part values, with
        /// `count`, `index` and `part` reading the list's count, its items and the part
        /// (specialised per layout by the caller, so the row loop carries no type dispatch).
        fn decode(
            &self,
            raw: &[u8],
            triangles: &mut [[u32; 3]],
            part_values: &mut [u32],
            count: impl Fn(&[u8]) -> i64 + Sync,
            index: impl Fn(&[u8]) -> i64 + Sync,
            part: impl Fn(&[u8]) -> i64 + Sync,
        ) -> Result<(), Stop> {
            raw.par_chunks(self.stride * ROWS_PER_TASK)
                .zip(triangles.par_chunks_mut(ROWS_PER_TASK))
                .zip(part_values.par_chunks_mut(ROWS_PER_TASK))
                .try_for_each(|((rows, triangles), part_values)| {
                    let rows = rows.chunks_exact(self.stride);
                    for ((row, t), part_value) in
                        rows.zip(triangles.iter_mut()).zip(part_values.iter_mut())
                    {
                        if count(&row[self.list_at..]) != 3 {
                            return Err(Stop::NotTriangle);
                        }
                        for (c, corner) in t.iter_mut().enumerate() {
                            let at = self.list_at + self.count_size + c * self.item_size;
                            let index = index(&row[at..]);
                            if index < 0 || index as u64 >= self.vertex_count {
                                return Err(Stop::BadIndex);
                            }
                            *corner = self.base + index as u32;
                        }
                        if let Some(at) = self.part_at {
                            // Raw values for now; mapped to part ids below.
                            *part_value =
                                u32::try_from(part(&row[at..])).map_err(|_| Stop::BadPart)?;
                        }
                    }
                    Ok(())
                })
        }
    }

    pub(super) fn read_faces(
        piece: &Piece,
        values: &mut impl Values,
        faces: &mut Faces,
        found: &mut Option<FoundRows>,
    ) -> Result<bool, FormatError> {
        let element = &piece.element;
        let (vertex_count, base) = (faces.vertex_count, faces.base);
        let Some((raw, big_endian)) = values.raw() else {
            return Ok(false);
        };
        // Layout: one integer corner list, any scalars; every list must hold 3 corners.
        let mut list = None;
        let mut stride = 0;
        let part = part_slot(element);
        let mut part_at = None;
        for (index, property) in element.properties.iter().enumerate() {
            match property {
                Property::List { name, count, item }
                    if list.is_none()
                        && item.is_integer()
                        && (name == "vertex_indices" || name == "vertex_index") =>
                {
                    list = Some((stride, *count, *item));
                    stride += count.size() + 3 * item.size();
                }
                Property::List { .. } => return Ok(false),
                Property::Scalar { ty, .. } => {
                    if Some(index) == part {
                        part_at = Some((stride, *ty));
                    }
                    stride += ty.size();
                }
            }
        }
        let Some((list_at, count_ty, item_ty)) = list else {
            return Ok(false);
        };
        let bytes = (element.count as usize).saturating_mul(stride);
        if bytes > raw.len() {
            return Ok(false);
        }
        let base = base as u32;
        // Decode straight into the soup's arrays; on a fallback they are cut back.
        let first = faces.soup.triangles.len();
        let count = element.count as usize;
        // Zero-filled in parallel: the fill is these arrays' first touch (160 MB at 10 M
        // triangles), whose page faults one thread would take alone.
        faces
            .soup
            .triangles
            .par_extend(rayon::iter::repeat_n([0; 3], count));
        faces
            .soup
            .triangle_parts
            .par_extend(rayon::iter::repeat_n(0, count));
        let layout = FaceLayout {
            stride,
            list_at,
            item_size: item_ty.size(),
            count_size: count_ty.size(),
            part_at: part_at.map(|(at, _)| at),
            vertex_count,
            base,
        };
        let (triangles, part_values) = (
            &mut faces.soup.triangles[first..],
            &mut faces.soup.triangle_parts[first..],
        );
        let raw = &raw[..bytes];
        // The layouts nearly every file uses get readers without per-value type dispatch;
        // every other layout takes the generic ones.
        let generic_part = |b: &[u8]| match part_at {
            Some((_, ty)) => integer(b, ty, big_endian),
            None => 0,
        };
        let u32_le = |b: &[u8]| i64::from(u32::from_le_bytes(four(b)));
        let i32_le = |b: &[u8]| i64::from(i32::from_le_bytes(four(b)));
        let u8_count = |b: &[u8]| i64::from(b[0]);
        let parts_u32_le = matches!(part_at, Some((_, Scalar::U32))) && !big_endian;
        let outcome = match (count_ty, item_ty, big_endian, parts_u32_le) {
            (Scalar::U8, Scalar::U32, false, true) => {
                layout.decode(raw, triangles, part_values, u8_count, u32_le, u32_le)
            }
            (Scalar::U8, Scalar::I32, false, true) => {
                layout.decode(raw, triangles, part_values, u8_count, i32_le, u32_le)
            }
            (Scalar::U8, Scalar::U32, false, false) => {
                layout.decode(raw, triangles, part_values, u8_count, u32_le, generic_part)
            }
            (Scalar::U8, Scalar::I32, false, false) => {
                layout.decode(raw, triangles, part_values, u8_count, i32_le, generic_part)
            }
            _ => layout.decode(
                raw,
                triangles,
                part_values,
                |b| integer(b, count_ty, big_endian),
                |b| integer(b, item_ty, big_endian),
                generic_part,
            ),
        };
        if outcome.is_err() {
            // Not all triangles, or bad data: the general reader decodes the element again
            // and reports the first problem in file order.
            faces.soup.triangles.truncate(first);
            faces.soup.triangle_parts.truncate(first);
            return Ok(false);
        }
        let mut triangle_parts = std::mem::take(&mut faces.soup.triangle_parts);
        let mut last: Option<(u32, u32)> = None;
        for value in &mut triangle_parts[first..] {
            let raw = part_at.map(|_| *value);
            *value = match (raw, last) {
                (Some(v), Some((previous, part))) if v == previous => part,
                _ => {
                    let part = faces.parts.part(raw.map(i64::from), faces.soup);
                    last = raw.map(|v| (v, part));
                    part
                }
            };
        }
        faces.soup.triangle_parts = triangle_parts;
        if let Some(found) = row_colors(element, raw, stride, big_endian) {
            faces.triangle_colors.extend(found);
        }
        // The layouts the map's rows are read again in ([`crate::mapped`]).
        let parts = match part_at {
            None => Some(FaceParts::Whole(faces.parts.file_part)),
            Some((at, Scalar::U32)) => Some(FaceParts::Values {
                at,
                table: faces.parts.table.clone(),
            }),
            Some(_) => None,
        };
        if let (Some(parts), Scalar::U8, Scalar::U32 | Scalar::I32, false) =
            (parts, count_ty, item_ty, big_endian)
        {
            *found = Some(FoundRows {
                address: raw.as_ptr() as usize,
                bytes,
                first_row: piece.first_row,
                stride,
                layout: RowLayout::Triangles(FaceRows {
                    list_at,
                    signed: item_ty == Scalar::I32,
                    vertex_count,
                    vertex_base: 0,
                    part_base: 0,
                    parts,
                }),
            });
        }
        values.skip_bytes(bytes);
        Ok(true)
    }
}
