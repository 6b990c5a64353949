//! Animated GIFs with one global palette from a deterministic median cut over every frame's
//! pixels: no random sampling, fixed tie-breaks, no dithering. The same frames give the same
//! bytes.

use gif::{DisposalMethod, Encoder, Frame, Repeat};

use crate::RenderError;
use crate::image::Image;

/// Bits kept per channel for the histogram and the colour look-up (5: 32768 cells).
const BITS: u32 = 5;
const CELLS: usize = 1 << (3 * BITS);

fn cell(px: &[u8]) -> usize {
    let s = 8 - BITS;
    (usize::from(px[0] >> s) << (2 * BITS))
        | (usize::from(px[1] >> s) << BITS)
        | usize::from(px[2] >> s)
}

/// One occupied histogram cell: its pixel count and the sums of its pixels' channels.
#[derive(Clone, Copy)]
struct Cell {
    key: usize,
    count: u64,
    sum: [u64; 3],
}

impl Cell {
    fn channel(&self, c: usize) -> usize {
        (self.key >> (BITS as usize * (2 - c))) & ((1 << BITS) - 1)
    }
}

/// A palette of at most `max_colors` colours for `frames` and, for every histogram cell, the
/// index of its nearest palette colour.
pub struct Palette {
    pub colors: Vec<[u8; 3]>,
    lookup: Vec<u8>,
}

impl Palette {
    pub fn median_cut<'a>(
        frames: impl IntoIterator<Item = &'a Image>,
        max_colors: usize,
    ) -> Palette {
        let max_colors = max_colors.clamp(1, 256);
        let mut hist = vec![
            Cell {
                key: 0,
                count: 0,
                sum: [0; 3],
            };
            CELLS
        ];
        for (i, h) in hist.iter_mut().enumerate() {
            h.key = i;
        }
        for frame in frames {
            for px in frame.rgb.chunks_exact(3) {
                let h = &mut hist[cell(px)];
                h.count += 1;
                for (sum, &v) in h.sum.iter_mut().zip(px) {
                    *sum += u64::from(v);
                }
            }
        }
        let cells: Vec<Cell> = hist.into_iter().filter(|h| h.count > 0).collect();
        // Boxes are index ranges into `order`, which is re-sorted within a box when it splits.
        let mut order = cells;
        let mut boxes: Vec<(usize, usize)> = if order.is_empty() {
            Vec::new()
        } else {
            vec![(0, order.len())]
        };
        while boxes.len() < max_colors {
            // The most populous box that can still split (ties: the earliest).
            let mut best: Option<(usize, u64)> = None;
            for (b, &(lo, hi)) in boxes.iter().enumerate() {
                if hi - lo < 2 {
                    continue;
                }
                let pop: u64 = order[lo..hi].iter().map(|c| c.count).sum();
                if best.is_none_or(|(_, p)| pop > p) {
                    best = Some((b, pop));
                }
            }
            let Some((b, pop)) = best else { break };
            let (lo, hi) = boxes[b];
            // Split along the channel with the widest range (ties: r, g, b).
            let range = |c: usize| {
                let it = order[lo..hi].iter().map(|x| x.channel(c));
                it.clone().max().unwrap_or(0) - it.min().unwrap_or(0)
            };
            let ranges = [range(0), range(1), range(2)];
            let axis = (0..3).fold(0, |a, c| if ranges[c] > ranges[a] { c } else { a });
            order[lo..hi].sort_by_key(|x| (x.channel(axis), x.key));
            // The weighted median, with at least one cell on each side.
            let mut acc = 0;
            let mut cut = lo + 1;
            for (i, x) in order[lo..hi].iter().enumerate() {
                acc += x.count;
                if 2 * acc >= pop {
                    cut = (lo + i + 1).clamp(lo + 1, hi - 1);
                    break;
                }
            }
            boxes[b] = (lo, cut);
            boxes.insert(b + 1, (cut, hi));
        }
        let colors: Vec<[u8; 3]> = boxes
            .iter()
            .map(|&(lo, hi)| {
                let n: u64 = order[lo..hi].iter().map(|c| c.count).sum();
                std::array::from_fn(|c| {
                    let s: u64 = order[lo..hi].iter().map(|x| x.sum[c]).sum();
                    ((s + n / 2) / n.max(1)) as u8
                })
            })
            .collect();
        let mut lookup = vec![0u8; CELLS];
        for x in &order {
            let mean: [i64; 3] = std::array::from_fn(|c| (x.sum[c] / x.count) as i64);
            let mut best = (0usize, i64::MAX);
            for (i, p) in colors.iter().enumerate() {
                let d: i64 = (0..3).map(|c| (mean[c] - i64::from(p[c])).pow(2)).sum();
                if d < best.1 {
                    best = (i, d);
                }
            }
            lookup[x.key] = best.0 as u8;
        }
        Palette { colors, lookup }
    }

    /// The palette index of every pixel of `image`.
    pub fn indices(&self, image: &Image) -> Vec<u8> {
        image
            .rgb
            .chunks_exact(3)
            .map(|px| self.lookup[cell(px)])
            .collect()
    }
}

/// An animated GIF of `frames` (all of one size, each side below 65536), each shown for its
/// delay in hundredths of a second, looping forever.
pub fn encode(frames: &[(Image, u16)]) -> crate::Result<Vec<u8>> {
    let Some((first, _)) = frames.first() else {
        return Ok(Vec::new());
    };
    if frames
        .iter()
        .any(|(f, _)| (f.width, f.height) != (first.width, first.height))
        || first.width > u32::from(u16::MAX)
        || first.height > u32::from(u16::MAX)
    {
        return Err(RenderError::Gif(
            "GIF frames must have one size below 65536 pixels a side".into(),
        ));
    }
    encode_frames(
        first,
        frames,
        &Palette::median_cut(frames.iter().map(|(f, _)| f), 256),
    )
    .map_err(|e| RenderError::Gif(e.to_string()))
}

fn encode_frames(
    first: &Image,
    frames: &[(Image, u16)],
    palette: &Palette,
) -> Result<Vec<u8>, gif::EncodingError> {
    let flat: Vec<u8> = palette.colors.iter().flatten().copied().collect();
    let (w, h) = (first.width as u16, first.height as u16);
    let mut out = Vec::new();
    {
        let mut enc = Encoder::new(&mut out, w, h, &flat)?;
        enc.set_repeat(Repeat::Infinite)?;
        for (image, delay) in frames {
            let mut frame = Frame::from_indexed_pixels(w, h, palette.indices(image), None);
            frame.delay = *delay;
            frame.dispose = DisposalMethod::Keep;
            enc.write_frame(&frame)?;
        }
    }
    Ok(out)
}
