//! RGB8 images: PNG encoding, box-filter downscaling, tiling, blending and text labels.

use ab_glyph::{Font, FontRef, PxScale, ScaleFont, point};

/// An 8-bit RGB image, rows top to bottom, pixels left to right, 3 bytes each.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

impl Image {
    /// A `width` × `height` image of one colour.
    pub fn filled(width: u32, height: u32, color: [u8; 3]) -> Self {
        let n = width as usize * height as usize;
        let mut rgb = Vec::with_capacity(n * 3);
        for _ in 0..n {
            rgb.extend_from_slice(&color);
        }
        Image { width, height, rgb }
    }

    fn index(&self, x: u32, y: u32) -> usize {
        (y as usize * self.width as usize + x as usize) * 3
    }

    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let i = self.index(x, y);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// The per-channel variance of the pixel values (0 for a blank image).
    pub fn channel_variance(&self) -> [f64; 3] {
        let n = (self.width as usize * self.height as usize).max(1) as f64;
        let mut sum = [0.0; 3];
        let mut sq = [0.0; 3];
        for px in self.rgb.chunks_exact(3) {
            for c in 0..3 {
                let v = f64::from(px[c]);
                sum[c] += v;
                sq[c] += v * v;
            }
        }
        std::array::from_fn(|c| sq[c] / n - (sum[c] / n).powi(2))
    }

    /// PNG bytes (8-bit RGB, default compression; the same image gives the same bytes).
    pub fn to_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            // Writing to a Vec cannot fail and the buffer matches the header.
            let mut writer = enc.write_header().expect("PNG header into a Vec");
            writer
                .write_image_data(&self.rgb)
                .expect("PNG data of the stated size into a Vec");
        }
        out
    }

    /// The image shrunk by an integer `factor`: each output pixel is the rounded mean of a
    /// `factor` × `factor` block (edge pixels that do not fill a block are dropped).
    pub fn downscale(&self, factor: u32) -> Image {
        if factor <= 1 {
            return self.clone();
        }
        let (w, h) = (self.width / factor, self.height / factor);
        let mut rgb = Vec::with_capacity(w as usize * h as usize * 3);
        let area = factor * factor;
        for y in 0..h {
            for x in 0..w {
                let mut acc = [0u32; 3];
                for dy in 0..factor {
                    for dx in 0..factor {
                        let p = self.pixel(x * factor + dx, y * factor + dy);
                        for c in 0..3 {
                            acc[c] += u32::from(p[c]);
                        }
                    }
                }
                for a in acc {
                    rgb.push(((a + area / 2) / area) as u8);
                }
            }
        }
        Image {
            width: w,
            height: h,
            rgb,
        }
    }

    /// Copies `src` into this image with its top-left corner at (`x`, `y`), clipped.
    pub fn paste(&mut self, src: &Image, x: u32, y: u32) {
        for sy in 0..src.height {
            let ty = y + sy;
            if ty >= self.height {
                break;
            }
            let w = src.width.min(self.width.saturating_sub(x));
            if w == 0 {
                return;
            }
            let s = src.index(0, sy);
            let t = self.index(x, ty);
            let n = w as usize * 3;
            self.rgb[t..t + n].copy_from_slice(&src.rgb[s..s + n]);
        }
    }

    /// Fills a rectangle, clipped.
    pub fn fill_rect(&mut self, x: u32, y: u32, w: u32, h: u32, color: [u8; 3]) {
        for ty in y..(y + h).min(self.height) {
            for tx in x..(x + w).min(self.width) {
                let i = self.index(tx, ty);
                self.rgb[i..i + 3].copy_from_slice(&color);
            }
        }
    }

    /// Blends `color` into pixel (x, y) with coverage `alpha` in [0, 1]; outside pixels are
    /// ignored.
    fn blend_pixel(&mut self, x: i64, y: i64, color: [u8; 3], alpha: f32) {
        if x < 0 || y < 0 || x >= i64::from(self.width) || y >= i64::from(self.height) {
            return;
        }
        let i = self.index(x as u32, y as u32);
        let a = alpha.clamp(0.0, 1.0);
        for (out, &c) in self.rgb[i..i + 3].iter_mut().zip(&color) {
            *out = (f32::from(*out) * (1.0 - a) + f32::from(c) * a).round() as u8;
        }
    }

    /// Draws `text` in DejaVu Sans at `px` pixels with its top-left corner at (x, y); returns
    /// the text's width in pixels.
    pub fn draw_text(&mut self, text: &str, x: f32, y: f32, px: f32, color: [u8; 3]) -> f32 {
        let font = font();
        let scale = PxScale::from(px);
        let scaled = font.as_scaled(scale);
        let baseline = y + scaled.ascent();
        let mut caret = x;
        let mut previous = None;
        for ch in text.chars() {
            let id = font.glyph_id(ch);
            if let Some(p) = previous {
                caret += scaled.kern(p, id);
            }
            let glyph = id.with_scale_and_position(scale, point(caret, baseline));
            caret += scaled.h_advance(id);
            previous = Some(id);
            if let Some(outline) = font.outline_glyph(glyph) {
                let b = outline.px_bounds();
                outline.draw(|gx, gy, coverage| {
                    self.blend_pixel(
                        b.min.x as i64 + i64::from(gx),
                        b.min.y as i64 + i64::from(gy),
                        color,
                        coverage,
                    );
                });
            }
        }
        caret - x
    }

    /// The width `text` would take at `px` pixels.
    pub fn text_width(text: &str, px: f32) -> f32 {
        let font = font();
        let scaled = font.as_scaled(PxScale::from(px));
        let mut w = 0.0;
        let mut previous = None;
        for ch in text.chars() {
            let id = font.glyph_id(ch);
            if let Some(p) = previous {
                w += scaled.kern(p, id);
            }
            w += scaled.h_advance(id);
            previous = Some(id);
        }
        w
    }
}

fn font() -> FontRef<'static> {
    FontRef::try_from_slice(dejavu::sans::regular()).expect("DejaVu Sans is a valid TrueType font")
}

/// Lays `tiles` side by side with `gap` pixels of `background` between them and a label band
/// of `label_px`-pixel text above each (no band when `label_px` is 0). Tiles may differ in
/// size; the strip is as tall as the tallest.
pub fn strip(tiles: &[(&Image, String)], gap: u32, label_px: u32, background: [u8; 3]) -> Image {
    let band = if label_px > 0 {
        label_px * 3 / 2 + 4
    } else {
        0
    };
    let width = tiles.iter().map(|(t, _)| t.width).sum::<u32>()
        + gap * (tiles.len() as u32).saturating_sub(1);
    let height = band + tiles.iter().map(|(t, _)| t.height).max().unwrap_or(0);
    let mut out = Image::filled(width, height, background);
    let mut x = 0;
    for (tile, label) in tiles {
        out.paste(tile, x, band);
        if band > 0 {
            let px = label_px as f32;
            let w = Image::text_width(label, px);
            let tx = x as f32 + ((tile.width as f32 - w) / 2.0).max(2.0);
            out.draw_text(label, tx, (band as f32 - px * 1.2) / 2.0, px, [20, 20, 20]);
        }
        x += tile.width + gap;
    }
    out
}
