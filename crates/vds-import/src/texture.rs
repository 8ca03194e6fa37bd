//! The average colour of a glTF base-colour texture (PNG or JPEG), for a part's one colour:
//! a review colours parts, not texels, so a textured part shows its texture's mean, times
//! the material's `baseColorFactor`.
//!
//! Images are hostile input like everything else: PNG rows are averaged as they are decoded
//! (memory stays one row, whatever the image's size); JPEG images are decoded whole and so
//! are refused beyond [`MAX_JPEG_SIDE`] pixels a side. Texels are sRGB (glTF's base colour
//! texture) and averaged in linear light; alpha is averaged as it is.

/// The largest JPEG width or height decoded (a JPEG decodes whole: 8192² RGB is 192 MiB).
pub const MAX_JPEG_SIDE: usize = 8192;

/// The linear value of an 8-bit sRGB component.
fn linear(component: u8) -> f64 {
    let c = f64::from(component) / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Running sums of linear RGBA.
#[derive(Default)]
struct Mean {
    sum: [f64; 4],
    count: u64,
    table: Vec<f64>,
}

impl Mean {
    fn new() -> Mean {
        Mean {
            table: (0..=255u8).map(linear).collect(),
            ..Default::default()
        }
    }

    /// Adds one texel of 8-bit sRGB colour and linear alpha.
    fn add(&mut self, [r, g, b, a]: [u8; 4]) {
        self.sum[0] += self.table[r as usize];
        self.sum[1] += self.table[g as usize];
        self.sum[2] += self.table[b as usize];
        self.sum[3] += f64::from(a) / 255.0;
        self.count += 1;
    }

    /// Adds a row of texels with `channels` 8-bit components each (1 grey, 2 grey and alpha,
    /// 3 RGB, 4 RGBA).
    fn add_row(&mut self, row: &[u8], channels: usize) {
        for texel in row.chunks_exact(channels) {
            self.add(match channels {
                1 => [texel[0], texel[0], texel[0], 255],
                2 => [texel[0], texel[0], texel[0], texel[1]],
                3 => [texel[0], texel[1], texel[2], 255],
                _ => [texel[0], texel[1], texel[2], texel[3]],
            });
        }
    }

    fn mean(&self) -> Result<[f64; 4], String> {
        if self.count == 0 {
            return Err("the image has no pixels".into());
        }
        Ok(self.sum.map(|s| s / self.count as f64))
    }
}

/// The mean linear RGBA of an encoded PNG or JPEG image.
///
/// # Errors
/// A format other than PNG or JPEG, an image that does not decode, or a JPEG larger than
/// [`MAX_JPEG_SIDE`].
pub fn average(bytes: &[u8]) -> Result<[f64; 4], String> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        average_png(bytes)
    } else if bytes.starts_with(&[0xFF, 0xD8]) {
        average_jpeg(bytes)
    } else {
        Err("neither PNG nor JPEG".into())
    }
}

fn average_png(bytes: &[u8]) -> Result<[f64; 4], String> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    // Palettes expanded, 16-bit components cut to 8: every row is then 1–4 bytes a texel.
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| format!("PNG: {e}"))?;
    let (colour, depth) = reader.output_color_type();
    if depth != png::BitDepth::Eight {
        return Err(format!("PNG: unexpected {depth:?} output"));
    }
    let channels = colour.samples();
    let mut mean = Mean::new();
    while let Some(row) = reader.next_row().map_err(|e| format!("PNG: {e}"))? {
        mean.add_row(row.data(), channels);
    }
    mean.mean()
}

fn average_jpeg(bytes: &[u8]) -> Result<[f64; 4], String> {
    use zune_jpeg::zune_core::bytestream::ZCursor;
    use zune_jpeg::zune_core::colorspace::ColorSpace;
    use zune_jpeg::zune_core::options::DecoderOptions;
    let options = DecoderOptions::default()
        .set_max_width(MAX_JPEG_SIDE)
        .set_max_height(MAX_JPEG_SIDE)
        .jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(bytes), options);
    let pixels = decoder.decode().map_err(|e| format!("JPEG: {e:?}"))?;
    let mut mean = Mean::new();
    mean.add_row(&pixels, 3);
    mean.mean()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A PNG of `width` × `height` texels of `colour` (RGBA8).
    pub(crate) fn png(width: u32, height: u32, texels: &[[u8; 4]]) -> Vec<u8> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, width, height);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().unwrap();
        let data: Vec<u8> = (0..(width * height) as usize)
            .flat_map(|i| texels[i % texels.len()])
            .collect();
        writer.write_image_data(&data).unwrap();
        writer.finish().unwrap();
        out
    }

    #[test]
    fn a_png_averages_in_linear_light() {
        // Half black, half white: linear mean 0.5, not sRGB 0.5.
        let mean = average(&png(4, 2, &[[0, 0, 0, 255], [255, 255, 255, 0]])).unwrap();
        for c in &mean[..3] {
            assert!((c - 0.5).abs() < 1e-9, "{mean:?}");
        }
        assert!((mean[3] - 0.5).abs() < 1e-9);
        let grey = average(&png(1, 1, &[[188, 188, 188, 255]])).unwrap();
        assert!((grey[0] - 0.5029).abs() < 1e-3, "{grey:?}");
    }

    #[test]
    fn what_is_not_an_image_is_an_error() {
        assert!(average(b"GIF89a").is_err());
        let mut broken = png(8, 8, &[[10, 20, 30, 255]]);
        broken.truncate(broken.len() / 2);
        assert!(average(&broken).is_err());
        assert!(average(&[0xFF, 0xD8, 0xFF, 0xE0, 0, 0]).is_err());
    }
}
