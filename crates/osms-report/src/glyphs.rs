//! Text on bitmaps with every glyph on one baseline.
//!
//! plotters' ab_glyph renderer places each glyph by its own pixel box, truncated toward zero
//! (`(size / 2 + top) as i32`): short glyphs rise and tall ones sink by up to a pixel each, so a
//! period sits above the digits beside it ("0·25") and letters jitter. [`Baseline`] wraps a
//! bitmap backend and rasterises text itself, each glyph positioned at its caret on the
//! baseline with sub-pixel precision; everything else, and the text's box and anchoring, is
//! plotters' own.

use ab_glyph::{Font, FontRef, ScaleFont, point};
use plotters::prelude::DrawingBackend;
use plotters_backend::{
    BackendColor, BackendCoord, BackendStyle, BackendTextStyle, DrawingErrorKind, text_anchor,
};

/// A backend whose text is drawn by [`glyph_pixels`] in DejaVu Sans (the only face the figures
/// register, for every family and style).
pub struct Baseline<B> {
    inner: B,
    font: FontRef<'static>,
}

impl<B: DrawingBackend> Baseline<B> {
    /// `None` only if the bundled font failed to parse.
    pub fn new(inner: B) -> Option<Baseline<B>> {
        let font = FontRef::try_from_slice(dejavu::sans::regular()).ok()?;
        Some(Baseline { inner, font })
    }
}

/// Coverage of every inked pixel of `text` at `size` px, in the text box's coordinates as
/// plotters lays it out: the caret advances by the glyphs' advances and kerning from x = 0,
/// and the baseline is at y = size / 2.
pub fn glyph_pixels(font: &FontRef<'_>, size: f32, text: &str) -> Vec<(i32, i32, f32)> {
    let scaled = font.as_scaled(size);
    let mut out = Vec::new();
    let mut caret = 0.0f32;
    let mut prev = None;
    for c in text.chars() {
        let id = scaled.glyph_id(c);
        if let Some(p) = prev {
            caret += scaled.kern(p, id);
        }
        prev = Some(id);
        let glyph = id.with_scale_and_position(size, point(caret, size / 2.0));
        caret += scaled.h_advance(id);
        if let Some(outline) = font.outline_glyph(glyph) {
            // px_bounds is whole pixels around the positioned outline; draw's coordinates are
            // relative to its corner, and the outline keeps its fractional offset inside.
            let b = outline.px_bounds();
            let (x0, y0) = (b.min.x as i32, b.min.y as i32);
            outline.draw(|x, y, c| out.push((x0 + x as i32, y0 + y as i32, c)));
        }
    }
    out
}

impl<B: DrawingBackend> DrawingBackend for Baseline<B> {
    type ErrorType = B::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.inner.get_size()
    }

    fn ensure_prepared(&mut self) -> Result<(), DrawingErrorKind<B::ErrorType>> {
        self.inner.ensure_prepared()
    }

    fn present(&mut self) -> Result<(), DrawingErrorKind<B::ErrorType>> {
        self.inner.present()
    }

    fn draw_pixel(
        &mut self,
        point: BackendCoord,
        color: BackendColor,
    ) -> Result<(), DrawingErrorKind<B::ErrorType>> {
        self.inner.draw_pixel(point, color)
    }

    fn draw_line<S: BackendStyle>(
        &mut self,
        from: BackendCoord,
        to: BackendCoord,
        style: &S,
    ) -> Result<(), DrawingErrorKind<B::ErrorType>> {
        self.inner.draw_line(from, to, style)
    }

    fn draw_rect<S: BackendStyle>(
        &mut self,
        upper_left: BackendCoord,
        bottom_right: BackendCoord,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<B::ErrorType>> {
        self.inner.draw_rect(upper_left, bottom_right, style, fill)
    }

    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> Result<(), DrawingErrorKind<B::ErrorType>> {
        self.inner.draw_path(path, style)
    }

    fn draw_circle<S: BackendStyle>(
        &mut self,
        center: BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<B::ErrorType>> {
        self.inner.draw_circle(center, radius, style, fill)
    }

    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> Result<(), DrawingErrorKind<B::ErrorType>> {
        self.inner.fill_polygon(vert, style)
    }

    fn estimate_text_size<S: BackendTextStyle>(
        &self,
        text: &str,
        style: &S,
    ) -> Result<(u32, u32), DrawingErrorKind<B::ErrorType>> {
        self.inner.estimate_text_size(text, style)
    }

    fn blit_bitmap(
        &mut self,
        pos: BackendCoord,
        size: (u32, u32),
        src: &[u8],
    ) -> Result<(), DrawingErrorKind<B::ErrorType>> {
        self.inner.blit_bitmap(pos, size, src)
    }

    /// plotters' own anchoring and rotation (the default `draw_text`), with the glyphs from
    /// [`glyph_pixels`].
    fn draw_text<S: BackendTextStyle>(
        &mut self,
        text: &str,
        style: &S,
        pos: BackendCoord,
    ) -> Result<(), DrawingErrorKind<B::ErrorType>> {
        let color = style.color();
        if color.alpha == 0.0 {
            return Ok(());
        }
        let ((min_x, min_y), (max_x, max_y)) = style
            .layout_box(text)
            .map_err(|e| DrawingErrorKind::FontError(Box::new(e)))?;
        let (width, height) = (max_x - min_x, max_y - min_y);
        let dx = match style.anchor().h_pos {
            text_anchor::HPos::Left => 0,
            text_anchor::HPos::Right => -width,
            text_anchor::HPos::Center => -width / 2,
        };
        let dy = match style.anchor().v_pos {
            text_anchor::VPos::Top => 0,
            text_anchor::VPos::Center => -height / 2,
            text_anchor::VPos::Bottom => -height,
        };
        let transform = style.transform();
        let (w, h) = self.get_size();
        for (x, y, coverage) in glyph_pixels(&self.font, style.size() as f32, text) {
            let (x, y) = transform.transform(x + dx - min_x, y + dy - min_y);
            let (x, y) = (pos.0 + x, pos.1 + y);
            if x >= 0 && x < w as i32 && y >= 0 && y < h as i32 {
                let ink = BackendColor {
                    alpha: color.alpha * f64::from(coverage),
                    rgb: color.rgb,
                };
                self.inner.draw_pixel((x, y), ink)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn font() -> FontRef<'static> {
        FontRef::try_from_slice(dejavu::sans::regular()).expect("DejaVu Sans parses")
    }

    /// The lowest row with at least a quarter of a pixel of ink among x in [x0, x1).
    fn bottom(pixels: &[(i32, i32, f32)], x0: i32, x1: i32) -> i32 {
        pixels
            .iter()
            .filter(|(x, _, c)| (x0..x1).contains(x) && *c > 0.25)
            .map(|&(_, y, _)| y)
            .max()
            .expect("ink in the column range")
    }

    #[test]
    fn a_period_sits_on_the_digits_baseline_at_every_size() {
        let font = font();
        // `1` and `.` both end flat on the baseline in DejaVu Sans.
        for size in [11.0f32, 12.0, 13.0, 15.0, 20.0] {
            let scaled = font.as_scaled(size);
            let advance = |c| scaled.h_advance(scaled.glyph_id(c));
            let pixels = glyph_pixels(&font, size, "1.1");
            let one_end = advance('1');
            let dot_end = one_end + advance('.');
            let digit = bottom(&pixels, 0, one_end as i32);
            let period = bottom(&pixels, one_end.ceil() as i32, dot_end as i32);
            assert_eq!(
                digit, period,
                "size {size}: 1 ends on row {digit}, . on {period}"
            );
            // The baseline is at y = size / 2; the row it cuts (or the one above it) is the last.
            assert_eq!(digit, (size / 2.0 - 0.25).ceil() as i32 - 1, "size {size}");
        }
    }

    #[test]
    fn glyphs_advance_by_the_layout_plotters_measures() {
        let font = font();
        let scaled = font.as_scaled(13.0);
        let text = "validate.deviation_scale";
        let pixels = glyph_pixels(&font, 13.0, text);
        let width: f32 = text
            .chars()
            .map(|c| scaled.h_advance(scaled.glyph_id(c)))
            .sum();
        let right = pixels.iter().map(|p| p.0).max().expect("ink");
        let left = pixels.iter().map(|p| p.0).min().expect("ink");
        assert!(
            left >= 0 && (right as f32) < width + 1.0,
            "{left}..{right} in {width}"
        );
        assert!(glyph_pixels(&font, 13.0, " ").is_empty());
    }
}
