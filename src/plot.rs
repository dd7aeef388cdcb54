//! Raster plotting for tolray: an RGB canvas with a data-to-pixel transform, 1-px lines, dots,
//! circles, a built-in 5x8 bitmap font, axes with "nice" ticks, heat maps and atomic PNG output.
//!
//! Nothing here panics on bad input: NaN/infinite coordinates are skipped, degenerate ranges are
//! widened and all geometry is clipped in `f64` before it is converted to integers.

use image::{ImageFormat, RgbImage};
use std::io::{self, Cursor};
use std::path::Path;

/// An RGB colour, `[r, g, b]`.
pub type Rgb = [u8; 3];

/// Series colours (Okabe-Ito, reordered so the strongest on white come first; yellow darkened).
pub const PALETTE: [Rgb; 8] = [
    [0, 114, 178],   // blue
    [213, 94, 0],    // vermillion
    [0, 158, 115],   // bluish green
    [204, 121, 167], // reddish purple
    [230, 159, 0],   // orange
    [86, 180, 233],  // sky blue
    [0, 0, 0],       // black
    [190, 170, 0],   // dark yellow
];

const BLACK: Rgb = [0, 0, 0];
const WHITE: Rgb = [255, 255, 255];
/// Largest accepted canvas side, in pixels.
const MAX_SIDE: u32 = 16384;
/// Glyph cell: 5x8 pixels drawn, 6 px advance; rows 0..=6 sit on the baseline, row 7 is the
/// descender.
const GLYPH_H: i64 = 8;
const ADVANCE: u64 = 6;
const TICK_LEN: i64 = 4;
/// Data ranges are clamped to +-HUGE so that their spans stay finite.
const HUGE: f64 = 1e300;

/// 5x8 glyphs for ASCII 32..=126: one byte per row (row 0 is the most significant byte),
/// bit 4 of each byte is the leftmost column.
#[rustfmt::skip]
const FONT: [u64; 95] = [
    0x0000000000000000, 0x0404040404000400, 0x0A0A0A0000000000, 0x0A0A1F0A1F0A0A00, // ' ' '!' '"' '#'
    0x040F140E051E0400, 0x1819020408130300, 0x0C12140815120D00, 0x0404080000000000, // '$' '%' '&' "'"
    0x0204080808040200, 0x0804020202040800, 0x0004150E15040000, 0x0004041F04040000, // '(' ')' '*' '+'
    0x00000000000C0C04, 0x0000001F00000000, 0x00000000000C0C00, 0x0102020408081000, // ',' '-' '.' '/'
    0x0E11131519110E00, 0x040C040404040E00, 0x0E11010204081F00, 0x1F02040201110E00, // '0' '1' '2' '3'
    0x02060A121F020200, 0x1F101E0101110E00, 0x0608101E11110E00, 0x1F01020408080800, // '4' '5' '6' '7'
    0x0E11110E11110E00, 0x0E11110F01020C00, 0x000C0C000C0C0000, 0x000C0C000C0C0408, // '8' '9' ':' ';'
    0x0204081008040200, 0x00001F001F000000, 0x0804020102040800, 0x0E11010204000400, // '<' '=' '>' '?'
    0x0E11171517100F00, 0x0E11111F11111100, 0x1E11111E11111E00, 0x0E11101010110E00, // '@' 'A' 'B' 'C'
    0x1C12111111121C00, 0x1F10101E10101F00, 0x1F10101E10101000, 0x0E11101711110F00, // 'D' 'E' 'F' 'G'
    0x1111111F11111100, 0x0E04040404040E00, 0x0702020202120C00, 0x1112141814121100, // 'H' 'I' 'J' 'K'
    0x1010101010101F00, 0x111B151511111100, 0x1111191513111100, 0x0E11111111110E00, // 'L' 'M' 'N' 'O'
    0x1E11111E10101000, 0x0E11111115120D00, 0x1E11111E14121100, 0x0F10100E01011E00, // 'P' 'Q' 'R' 'S'
    0x1F04040404040400, 0x1111111111110E00, 0x11111111110A0400, 0x1111111515150A00, // 'T' 'U' 'V' 'W'
    0x11110A040A111100, 0x11110A0404040400, 0x1F01020408101F00, 0x0E08080808080E00, // 'X' 'Y' 'Z' '['
    0x1008080402020100, 0x0E02020202020E00, 0x040A110000000000, 0x000000000000001F, // '\\' ']' '^' '_'
    0x0804000000000000, 0x00000E010F110F00, 0x10101E1111111E00, 0x00000E1010110E00, // '`' 'a' 'b' 'c'
    0x01010F1111110F00, 0x00000E111F100E00, 0x0609081C08080800, 0x00000F11110F010E, // 'd' 'e' 'f' 'g'
    0x1010161911111100, 0x04000C0404040E00, 0x020006020202120C, 0x1010121418141200, // 'h' 'i' 'j' 'k'
    0x0C04040404040E00, 0x00001A1515111100, 0x0000161911111100, 0x00000E1111110E00, // 'l' 'm' 'n' 'o'
    0x00001E11111E1010, 0x00000F11110F0101, 0x0000161910101000, 0x00000F100E011E00, // 'p' 'q' 'r' 's'
    0x08081C0808090600, 0x0000111111130D00, 0x00001111110A0400, 0x0000111115150A00, // 't' 'u' 'v' 'w'
    0x0000110A040A1100, 0x00001111110F010E, 0x00001F0204081F00, 0x0304040804040300, // 'x' 'y' 'z' '{'
    0x0404040404040404, 0x1804040204041800, 0x00000D1200000000, // '|' '}' '~'
];
const DEGREE: u64 = 0x0C12120C00000000;
const LAMBDA: u64 = 0x1804040A0A111100;
const PLUS_MINUS: u64 = 0x04041F0404001F00;

/// Inferno-like colour map anchors at t = 0, 0.1, ..., 1.
const INFERNO: [Rgb; 11] = [
    [0, 0, 4],
    [22, 11, 57],
    [66, 10, 104],
    [106, 23, 110],
    [147, 38, 103],
    [188, 55, 84],
    [221, 81, 58],
    [243, 120, 25],
    [252, 165, 10],
    [246, 215, 70],
    [252, 255, 164],
];

/// An RGB raster canvas with a data-to-pixel mapping, used for every picture tolray writes.
///
/// Data coordinates map linearly onto the plot rectangle set by [`Canvas::set_view`]: the low end
/// of each range lands on the centre of the first pixel of the rectangle and the high end on the
/// last one, with y pointing up. Until `set_view` is called the rectangle is the whole canvas and
/// both ranges are `(0, 1)`. Data primitives are clipped to the canvas, not to the plot rectangle.
/// [`Canvas::axes`] and [`Canvas::title`] draw outside the rectangle, so leave margins of about
/// 60 px on the left, 40 px on top, 32 px at the bottom and 10 px on the right.
#[derive(Clone)]
pub struct Canvas {
    img: RgbImage,
    /// Plot rectangle in pixels: x0, y0, w, h (w and h at least 1).
    rect: (u32, u32, u32, u32),
    xr: (f64, f64),
    yr: (f64, f64),
}

impl Canvas {
    /// White canvas of `width` x `height` pixels (each side clamped to 1..=16384).
    #[must_use]
    pub fn new(width: u32, height: u32) -> Canvas {
        let (w, h) = (width.clamp(1, MAX_SIDE), height.clamp(1, MAX_SIDE));
        Canvas {
            img: RgbImage::from_pixel(w, h, image::Rgb(WHITE)),
            rect: (0, 0, w, h),
            xr: (0.0, 1.0),
            yr: (0.0, 1.0),
        }
    }

    /// Sets the data window shown in the plot rectangle (pixel rect x0, y0, w, h); y up in data
    /// space.
    ///
    /// Ranges are sorted, non-finite ends are replaced, and empty ranges are widened (by 5 % of
    /// their value, or to +-1 around zero). `equal_aspect`: if true, enlarge the smaller data range
    /// about its centre so 1 data unit is the same number of pixels in x and y.
    pub fn set_view(
        &mut self,
        px_rect: (u32, u32, u32, u32),
        x_range: (f64, f64),
        y_range: (f64, f64),
        equal_aspect: bool,
    ) {
        let (x0, y0, w, h) = px_rect;
        self.rect = (x0, y0, w.max(1), h.max(1));
        self.xr = sanitize_range(x_range);
        self.yr = sanitize_range(y_range);
        if equal_aspect {
            let (sx, sy) = self.scales();
            if sx > sy {
                self.xr = widen(self.xr, sx / sy);
            } else if sy > sx {
                self.yr = widen(self.yr, sy / sx);
            }
        }
    }

    /// Data -> pixel (f64 pixel coordinates; integer values are pixel centres).
    #[must_use]
    pub fn to_px(&self, x: f64, y: f64) -> (f64, f64) {
        let (x0, y0, _, h) = self.rect;
        let (sx, sy) = self.scales();
        (
            f64::from(x0) + (x - self.xr.0) * sx,
            f64::from(y0) + f64::from(h - 1) - (y - self.yr.0) * sy,
        )
    }

    /// Draws a 1-px Bresenham line between two data points, clipped to the canvas.
    /// Segments with a NaN or infinite end are skipped.
    pub fn line(&mut self, a: (f64, f64), b: (f64, f64), color: Rgb) {
        if let Some((p, q)) = self.clip(a, b) {
            self.segment_px(p, q, color);
        }
    }

    /// Draws lines through consecutive data points; a non-finite point breaks the line.
    /// A single point draws one pixel.
    pub fn polyline(&mut self, pts: &[(f64, f64)], color: Rgb) {
        if let [p] = pts {
            self.line(*p, *p, color);
        }
        for w in pts.windows(2) {
            self.line(w[0], w[1], color);
        }
    }

    /// Filled dot of radius `r_px` pixels at a data point (r_px 0 => single pixel). The centre is
    /// snapped to the nearest pixel and pixels within `r_px + 0.5` of it are set.
    pub fn dot(&mut self, p: (f64, f64), r_px: f64, color: Rgb) {
        let (cx, cy) = self.to_px(p.0, p.1);
        if !(cx.is_finite() && cy.is_finite()) {
            return;
        }
        let (cx, cy) = (cx.round(), cy.round());
        let r = if r_px > 0.0 { r_px.min(1e5) + 0.5 } else { 0.5 };
        let (w, h) = self.img.dimensions();
        let span = |c: f64, n: u32| {
            let lo = (c - r).ceil().max(0.0) as i64;
            let hi = (c + r).floor().min(f64::from(n - 1)) as i64;
            lo..=hi
        };
        for y in span(cy, h) {
            for x in span(cx, w) {
                let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                if dx * dx + dy * dy <= r * r {
                    self.put(x, y, color);
                }
            }
        }
    }

    /// Circle outline in data coordinates (radius in data units; an ellipse on screen when the
    /// view is not equal-aspect). Drawn as a polygon of 16..=1024 segments.
    pub fn circle(&mut self, centre: (f64, f64), radius: f64, color: Rgb) {
        let r = radius.abs();
        if !(centre.0.is_finite() && centre.1.is_finite() && r.is_finite()) {
            return;
        }
        let (sx, sy) = self.scales();
        let r_px = (r * sx.max(sy)).min(1e6);
        let n = ((r_px * std::f64::consts::PI).ceil() as usize).clamp(16, 1024);
        let pts: Vec<_> = (0..=n)
            .map(|i| {
                let t = std::f64::consts::TAU * i as f64 / n as f64;
                (centre.0 + r * t.cos(), centre.1 + r * t.sin())
            })
            .collect();
        self.polyline(&pts, color);
    }

    /// Pixel-space rectangle with top-left corner (x, y), outline or filled; for frames and
    /// legends.
    pub fn rect_px(&mut self, x: i32, y: i32, w: u32, h: u32, color: Rgb, filled: bool) {
        if w == 0 || h == 0 {
            return;
        }
        let (x0, y0) = (i64::from(x), i64::from(y));
        let (x1, y1) = (x0 + i64::from(w) - 1, y0 + i64::from(h) - 1);
        if filled {
            self.fill(x0, y0, x1, y1, color);
        } else {
            self.fill(x0, y0, x1, y0, color);
            self.fill(x0, y1, x1, y1, color);
            self.fill(x0, y0, x0, y1, color);
            self.fill(x1, y0, x1, y1, color);
        }
    }

    /// Text with the built-in 5x8 bitmap font (ASCII 32..=126, plus 'µ'/'μ' drawn as 'u', '°',
    /// 'λ' and '±'; anything else is drawn as '?'). `scale` is an integer pixel multiplier
    /// (clamped to 1..=64). Top-left anchored at pixel (x, y); caps are 7 * scale px high and
    /// descenders reach 8 * scale px. Returns the width drawn in px (see [`Canvas::text_width`]).
    pub fn text_px(&mut self, x: i32, y: i32, s: &str, scale: u32, color: Rgb) -> u32 {
        let k = i64::from(scale.clamp(1, 64));
        let right = i64::from(self.img.width());
        for (i, ch) in s.chars().enumerate() {
            let gx = i64::from(x) + i as i64 * ADVANCE as i64 * k;
            if gx >= right {
                break;
            }
            let bits = glyph(ch);
            for row in 0..8 {
                let line = (bits >> (56 - 8 * row)) & 0x1F;
                for col in 0..5 {
                    if line & (0x10 >> col) != 0 {
                        let (px, py) = (gx + col * k, i64::from(y) + row * k);
                        self.fill(px, py, px + k - 1, py + k - 1, color);
                    }
                }
            }
        }
        Self::text_width(s, scale)
    }

    /// Width in pixels `text_px` would use: `(6 * chars - 1) * scale`, 0 for an empty string.
    #[must_use]
    pub fn text_width(s: &str, scale: u32) -> u32 {
        let n = s.chars().count() as u64;
        let k = u64::from(scale.clamp(1, 64));
        u32::try_from((n * ADVANCE).saturating_sub(1) * k).unwrap_or(u32::MAX)
    }

    /// Axes frame one pixel outside the plot rectangle with ~5 "nice" ticks (1/2/5 x 10^k) on
    /// each axis pointing outwards, tick labels, the x label centred below and the y label at the
    /// top-left above the axis. Fewer ticks are used when labels would collide.
    pub fn axes(&mut self, x_label: &str, y_label: &str) {
        let (x0, y0, w, h) = self.rect;
        let (x0, y0, w, h) = (i64::from(x0), i64::from(y0), i64::from(w), i64::from(h));
        self.fill(x0 - 1, y0 - 1, x0 + w, y0 - 1, BLACK);
        self.fill(x0 - 1, y0 + h, x0 + w, y0 + h, BLACK);
        self.fill(x0 - 1, y0 - 1, x0 - 1, y0 + h, BLACK);
        self.fill(x0 + w, y0 - 1, x0 + w, y0 + h, BLACK);

        let label_y = y0 + h + TICK_LEN + 3;
        let need_x = |s: &str| f64::from(Self::text_width(s, 1)) + 8.0;
        for t in fitting_ticks(self.xr, w, need_x) {
            let px = self.to_px(t, self.yr.0).0.round() as i64;
            self.fill(px, y0 + h + 1, px, y0 + h + TICK_LEN, BLACK);
            let s = fmt_tick(t);
            self.text_at(px - i64::from(Self::text_width(&s, 1)) / 2, label_y, &s, 1);
        }
        let right = x0 - 1 - TICK_LEN - 3;
        let mut left = right;
        for t in fitting_ticks(self.yr, h, |_| GLYPH_H as f64 + 4.0) {
            let py = self.to_px(self.xr.0, t).1.round() as i64;
            self.fill(x0 - 1 - TICK_LEN, py, x0 - 2, py, BLACK);
            let s = fmt_tick(t);
            let lx = right - i64::from(Self::text_width(&s, 1));
            self.text_at(lx, py - 3, &s, 1);
            left = left.min(lx);
        }
        let xl = x0 + w / 2 - i64::from(Self::text_width(x_label, 1)) / 2;
        self.text_at(xl, label_y + GLYPH_H + 4, x_label, 1);
        self.text_at(left.min(x0).max(2), y0 - 5 - GLYPH_H, y_label, 1);
    }

    /// Title centred at the top of the canvas (4 px from the top; scale 2 if it fits, else 1).
    pub fn title(&mut self, s: &str) {
        let cw = i64::from(self.img.width());
        let scale = if i64::from(Self::text_width(s, 2)) + 8 <= cw {
            2
        } else {
            1
        };
        let x = (cw - i64::from(Self::text_width(s, scale))) / 2;
        self.text_at(x, 4, s, scale);
    }

    /// Heat map: draws a row-major `w x h` grid of non-negative values into pixel rect
    /// (x0, y0, pw, ph) (nearest-neighbour scaling, clipped to the canvas), colour map
    /// "inferno"-like (black -> purple -> orange -> yellow), normalized to `max` (values above
    /// clamp; NaN and negatives are black).
    /// Row 0 at the top. A non-finite or non-positive `max` means "use the largest finite value".
    /// Nothing is drawn if `values` holds fewer than `w * h` entries.
    pub fn heatmap_px(
        &mut self,
        rect: (u32, u32, u32, u32),
        values: &[f64],
        w: usize,
        h: usize,
        max: f64,
    ) {
        let (rx, ry, pw, ph) = rect;
        if pw == 0
            || ph == 0
            || w == 0
            || h == 0
            || w.checked_mul(h).map_or(true, |n| values.len() < n)
        {
            return;
        }
        let max = if max.is_finite() && max > 0.0 {
            max
        } else {
            values
                .iter()
                .copied()
                .filter(|v| v.is_finite())
                .fold(0.0, f64::max)
        };
        let (cw, ch) = self.img.dimensions();
        for py in 0..ph.min(ch.saturating_sub(ry)) {
            let j = (u64::from(py) * h as u64 / u64::from(ph)) as usize;
            for px in 0..pw.min(cw.saturating_sub(rx)) {
                let i = (u64::from(px) * w as u64 / u64::from(pw)) as usize;
                let v = values[j * w + i];
                let t = if max > 0.0 && v > 0.0 {
                    (v / max).min(1.0)
                } else {
                    0.0
                };
                self.img.put_pixel(rx + px, ry + py, image::Rgb(inferno(t)));
            }
        }
    }

    /// Writes PNG atomically: the image is encoded in memory, written to a hidden temporary file
    /// in the same directory, synced, then renamed over `path`; on error no file is left behind.
    ///
    /// # Errors
    /// Any I/O error from creating, writing or renaming the file (e.g. a missing directory), or
    /// `InvalidInput` if `path` has no file name.
    pub fn save_png(&self, path: &Path) -> io::Result<()> {
        let mut bytes = Vec::new();
        self.img
            .write_to(&mut Cursor::new(&mut bytes), ImageFormat::Png)
            .map_err(io::Error::other)?;
        crate::error::write_atomic(path, &bytes).map_err(|e| match e.kind {
            crate::ErrorKind::Argument => io::Error::new(io::ErrorKind::InvalidInput, e.message),
            _ => io::Error::other(e.message),
        })
    }

    /// Access to the raw image (for tests).
    pub fn image(&self) -> &image::RgbImage {
        &self.img
    }

    /// Pixels per data unit in x and y.
    fn scales(&self) -> (f64, f64) {
        let (_, _, w, h) = self.rect;
        (
            f64::from((w - 1).max(1)) / (self.xr.1 - self.xr.0),
            f64::from((h - 1).max(1)) / (self.yr.1 - self.yr.0),
        )
    }

    /// Pixel -> data (inverse of `to_px`).
    fn to_data(&self, px: f64, py: f64) -> (f64, f64) {
        let (x0, y0, _, h) = self.rect;
        let (sx, sy) = self.scales();
        (
            self.xr.0 + (px - f64::from(x0)) / sx,
            self.yr.0 + (f64::from(y0) + f64::from(h - 1) - py) / sy,
        )
    }

    /// Liang-Barsky clipping of a data segment against the canvas, done in data space on halved
    /// coordinates so that differences of huge values cannot overflow. A clipped end is put exactly
    /// on the edge that cut it, with the other coordinate from the slope (accurate even when the
    /// ends are near f64::MAX). Returns pixel coordinates.
    fn clip(&self, a: (f64, f64), b: (f64, f64)) -> Option<((f64, f64), (f64, f64))> {
        if ![a.0, a.1, b.0, b.1].iter().all(|v| v.is_finite()) {
            return None;
        }
        let (w, h) = self.img.dimensions();
        let (xmin, ymin) = self.to_data(0.0, f64::from(h - 1));
        let (xmax, ymax) = self.to_data(f64::from(w - 1), 0.0);
        let bounds = [xmin, xmax, ymin, ymax];
        let (ax, ay) = (a.0 / 2.0, a.1 / 2.0);
        let (dx, dy) = (b.0 / 2.0 - ax, b.1 / 2.0 - ay);
        // (t, index of the edge that set it) for the start and the end of the visible part
        let (mut start, mut end) = ((0.0, None), (1.0, None));
        let edges = [
            (-dx, ax - xmin / 2.0),
            (dx, xmax / 2.0 - ax),
            (-dy, ay - ymin / 2.0),
            (dy, ymax / 2.0 - ay),
        ];
        for (i, (p, q)) in edges.into_iter().enumerate() {
            let t = q / p;
            if p == 0.0 && q < 0.0 {
                return None;
            } else if p < 0.0 && t > start.0 {
                start = (t, Some(i));
            } else if p > 0.0 && t < end.0 {
                end = (t, Some(i));
            }
        }
        if start.0 > end.0 {
            return None;
        }
        let point = |(t, edge): (f64, Option<usize>), original: (f64, f64)| {
            let on_edge = match edge {
                None => original,
                Some(i @ 0..=1) => (bounds[i], 2.0 * (ay + (bounds[i] / 2.0 - ax) * (dy / dx))),
                Some(i) => (2.0 * (ax + (bounds[i] / 2.0 - ay) * (dx / dy)), bounds[i]),
            };
            let (x, y) = if on_edge.0.is_finite() && on_edge.1.is_finite() {
                on_edge
            } else {
                (2.0 * (ax + t * dx), 2.0 * (ay + t * dy))
            };
            // The exact point lies in the box, so clamping only removes rounding error.
            self.to_px(x.clamp(xmin, xmax), y.clamp(ymin, ymax))
        };
        Some((point(start, a), point(end, b)))
    }

    /// Bresenham between two (already clipped) pixel positions.
    fn segment_px(&mut self, p: (f64, f64), q: (f64, f64), color: Rgb) {
        let (w, h) = self.img.dimensions();
        let snap = |v: f64, n: u32| v.round().clamp(0.0, f64::from(n - 1)) as i64;
        let (mut x, mut y) = (snap(p.0, w), snap(p.1, h));
        let (x1, y1) = (snap(q.0, w), snap(q.1, h));
        let (dx, dy) = ((x1 - x).abs(), -(y1 - y).abs());
        let (sx, sy) = ((x1 - x).signum(), (y1 - y).signum());
        let mut err = dx + dy;
        loop {
            self.put(x, y, color);
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// Sets one pixel if it is on the canvas.
    fn put(&mut self, x: i64, y: i64, color: Rgb) {
        let (w, h) = self.img.dimensions();
        if (0..i64::from(w)).contains(&x) && (0..i64::from(h)).contains(&y) {
            self.img.put_pixel(x as u32, y as u32, image::Rgb(color));
        }
    }

    /// Fills the inclusive pixel box (x0, y0)..=(x1, y1), clipped to the canvas.
    fn fill(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, color: Rgb) {
        let (w, h) = self.img.dimensions();
        let (x0, x1) = (x0.max(0), x1.min(i64::from(w) - 1));
        let (y0, y1) = (y0.max(0), y1.min(i64::from(h) - 1));
        for y in y0..=y1 {
            for x in x0..=x1 {
                self.img.put_pixel(x as u32, y as u32, image::Rgb(color));
            }
        }
    }

    /// `text_px` with i64 coordinates (saturated into i32) in black.
    fn text_at(&mut self, x: i64, y: i64, s: &str, scale: u32) {
        let sat = |v: i64| v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
        self.text_px(sat(x), sat(y), s, scale, BLACK);
    }
}

/// "Nice" tick positions inside [lo, hi] (1, 2, 5 x 10^k steps), about `target` of them.
///
/// The bounds may come in either order; an empty range is widened like [`Canvas::set_view`]
/// does, and a non-finite bound gives no ticks. Values are exact decimal multiples of the step
/// (e.g. `0.3`, not `0.30000000000000004`).
#[must_use]
pub fn nice_ticks(lo: f64, hi: f64, target: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) {
        return Vec::new();
    }
    let (lo, hi) = sanitize_range((lo, hi));
    let raw = (hi / 2.0 - lo / 2.0) / target.clamp(1, 100) as f64 * 2.0;
    if !(raw.is_finite() && raw > 0.0) {
        return Vec::new();
    }
    let e = raw.log10().floor();
    let norm = raw / 10f64.powf(e);
    let m = match norm {
        n if n < 1.5 => 1.0,
        n if n < 3.0 => 2.0,
        n if n < 7.0 => 5.0,
        _ => 10.0,
    };
    let step = m * 10f64.powf(e);
    let (k0, k1) = ((lo / step - 1e-9).ceil(), (hi / step + 1e-9).floor());
    if !(step.is_finite() && step > 0.0 && k1 - k0 < 1000.0) {
        return Vec::new();
    }
    let e = e as i32;
    // k * m is an exact integer and 10^|e| is exact up to 1e22, so the division rounds once.
    let value = |k: f64| {
        let n = k * m;
        let v = if e >= 0 {
            n * 10f64.powi(e)
        } else {
            n / 10f64.powi(-e)
        };
        v + 0.0 // -0.0 becomes 0.0
    };
    (0..=(k1 - k0) as i64)
        .map(|i| value(k0 + i as f64))
        .collect()
}

/// Formats a tick value compactly: up to 6 significant digits without trailing zeros, fixed
/// notation for 1e-3 <= |v| < 1e6 and scientific (`2.5e-5`, `1.5e6`) otherwise; zero is `0`.
#[must_use]
pub fn fmt_tick(v: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    if !v.is_finite() {
        return v.to_string();
    }
    let a = v.abs();
    if (1e-3..1e6).contains(&a) {
        let decimals = (5 - a.log10().floor() as i32).clamp(0, 8) as usize;
        trim_zeros(&format!("{v:.decimals$}")).to_string()
    } else {
        let s = format!("{v:.5e}");
        let (mantissa, exp) = s.split_once('e').unwrap_or((&s, "0"));
        format!("{}e{exp}", trim_zeros(mantissa))
    }
}

/// Strips trailing fractional zeros and a dangling '.' ("2.500" -> "2.5", "3.0" -> "3").
fn trim_zeros(s: &str) -> &str {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        s
    }
}

/// Sorts a range, replaces non-finite ends, clamps to +-HUGE and widens empty ranges.
fn sanitize_range((a, b): (f64, f64)) -> (f64, f64) {
    let (lo, hi) = match (a.is_finite(), b.is_finite()) {
        (true, true) => (a.min(b), a.max(b)),
        (true, false) => (a, a),
        (false, true) => (b, b),
        (false, false) => (0.0, 1.0),
    };
    let (lo, hi) = (lo.clamp(-HUGE, HUGE), hi.clamp(-HUGE, HUGE));
    if hi - lo > lo.abs().max(hi.abs()) * 1e-12 && hi - lo > 1e-200 {
        return (lo, hi);
    }
    let mid = lo / 2.0 + hi / 2.0;
    let pad = if mid.abs() > 1e-200 {
        mid.abs() * 0.05
    } else {
        1.0
    };
    (mid - pad, mid + pad)
}

/// Scales a range about its centre by `factor` (>= 1), clamped to +-HUGE.
fn widen((lo, hi): (f64, f64), factor: f64) -> (f64, f64) {
    let (mid, half) = (lo / 2.0 + hi / 2.0, (hi / 2.0 - lo / 2.0) * factor);
    ((mid - half).max(-HUGE), (mid + half).min(HUGE))
}

/// The densest of 5..=1 target tick counts whose labels fit: `need(label)` is the pixel spacing a
/// label requires, `len` the axis length in pixels.
fn fitting_ticks(range: (f64, f64), len: i64, need: impl Fn(&str) -> f64) -> Vec<f64> {
    let px_per_unit = (len - 1).max(1) as f64 / (range.1 - range.0);
    let mut ticks = Vec::new();
    for target in (1..=5).rev() {
        ticks = nice_ticks(range.0, range.1, target);
        let spacing = match ticks.as_slice() {
            [a, b, ..] => (b - a) * px_per_unit,
            _ => f64::INFINITY,
        };
        if ticks.iter().all(|&t| need(&fmt_tick(t)) <= spacing) {
            break;
        }
    }
    ticks
}

/// Bitmap of the glyph drawn for `ch`.
fn glyph(ch: char) -> u64 {
    match ch {
        ' '..='~' => FONT[ch as usize - 32],
        'µ' | 'μ' => FONT['u' as usize - 32],
        '°' => DEGREE,
        'λ' => LAMBDA,
        '±' => PLUS_MINUS,
        _ => FONT['?' as usize - 32],
    }
}

/// Inferno-like colour for t in [0, 1] (NaN is black).
fn inferno(t: f64) -> Rgb {
    let x = if t > 0.0 { t.min(1.0) * 10.0 } else { 0.0 };
    let i = (x.floor() as usize).min(9);
    let f = x - i as f64;
    let (a, b) = (INFERNO[i], INFERNO[i + 1]);
    std::array::from_fn(|c| {
        (f64::from(a[c]) + (f64::from(b[c]) - f64::from(a[c])) * f).round() as u8
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs;

    const RED: Rgb = [255, 0, 0];

    /// Coordinates of all non-white pixels, row by row.
    fn inked(c: &Canvas) -> Vec<(u32, u32)> {
        c.image()
            .enumerate_pixels()
            .filter(|(_, _, p)| p.0 != WHITE)
            .map(|(x, y, _)| (x, y))
            .collect()
    }

    /// A 20x10 canvas whose data coordinates equal pixel coordinates with y flipped (y_px = 9 - y).
    fn grid() -> Canvas {
        let mut c = Canvas::new(20, 10);
        c.set_view((0, 0, 20, 10), (0.0, 19.0), (0.0, 9.0), false);
        c
    }

    #[test]
    fn nice_ticks_ranges() {
        assert_eq!(nice_ticks(0.0, 10.0, 5), [0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        assert_eq!(nice_ticks(10.0, 0.0, 5), [0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        assert_eq!(nice_ticks(-1.0, 1.0, 5), [-1.0, -0.5, 0.0, 0.5, 1.0]);
        assert_eq!(
            nice_ticks(0.0, 0.3, 5),
            [0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3]
        );
        assert_eq!(nice_ticks(0.0, 2e-4, 5), [0.0, 5e-5, 1e-4, 1.5e-4, 2e-4]);
        assert_eq!(nice_ticks(-3.7, 12.2, 5), [0.0, 5.0, 10.0]);
        assert_eq!(
            nice_ticks(-3.7, 12.2, 8),
            [-2.0, 0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0]
        );
        assert_eq!(nice_ticks(3.0, 3.0, 3), [2.9, 3.0, 3.1]); // widened to 2.85..3.15
        assert!(nice_ticks(0.0, 0.0, 5).contains(&0.0));
        assert!(nice_ticks(f64::NAN, 1.0, 5).is_empty());
        assert!(nice_ticks(0.0, f64::INFINITY, 5).is_empty());
        assert!(!nice_ticks(-1e308, 1e308, 5).is_empty());
        assert!(nice_ticks(0.0, 1.0, usize::MAX).len() <= 101);
        assert!(!nice_ticks(0.0, 1.0, 0).is_empty());
        assert!(nice_ticks(0.0, 1.0, 5).iter().all(|t| t.is_sign_positive()));
    }

    #[test]
    fn tick_formatting() {
        let cases = [
            (0.0, "0"),
            (-0.0, "0"),
            (0.5, "0.5"),
            (-3.0, "-3"),
            (10.0, "10"),
            (0.001, "0.001"),
            (0.1 + 0.2, "0.3"),
            (123456.0, "123456"),
            (2.5e-5, "2.5e-5"),
            (-1e-4, "-1e-4"),
            (1.5e6, "1.5e6"),
            (1.23456789e9, "1.23457e9"),
            (f64::NAN, "NaN"),
            (f64::NEG_INFINITY, "-inf"),
        ];
        for (v, s) in cases {
            assert_eq!(fmt_tick(v), s, "{v}");
        }
    }

    #[test]
    fn to_px_maps_corners_to_rect_pixels() {
        let mut c = Canvas::new(200, 100);
        c.set_view((10, 20, 101, 51), (0.0, 100.0), (0.0, 50.0), false);
        assert_eq!(c.to_px(0.0, 0.0), (10.0, 70.0));
        assert_eq!(c.to_px(100.0, 50.0), (110.0, 20.0));
        assert_eq!(c.to_px(0.0, 50.0), (10.0, 20.0));
        assert_eq!(c.to_px(50.0, 25.0), (60.0, 45.0));
        // reversed and degenerate ranges
        c.set_view((10, 20, 101, 51), (100.0, 0.0), (5.0, 5.0), false);
        assert_eq!(c.to_px(0.0, 4.75), (10.0, 70.0));
        assert_eq!(c.to_px(100.0, 5.25), (110.0, 20.0));
    }

    #[test]
    fn equal_aspect_widens_the_smaller_range() {
        let mut c = Canvas::new(300, 200);
        c.set_view((0, 0, 201, 101), (0.0, 10.0), (0.0, 10.0), true);
        // y needs 10 px/unit, x would get 20: x range becomes -5..15 about its centre.
        assert_eq!(c.to_px(-5.0, 0.0), (0.0, 100.0));
        assert_eq!(c.to_px(15.0, 10.0), (200.0, 0.0));
        assert_eq!(c.to_px(5.0, 5.0), (100.0, 50.0));
        let (a, b) = (c.to_px(0.0, 0.0), c.to_px(1.0, 1.0));
        assert_eq!((b.0 - a.0, a.1 - b.1), (10.0, 10.0));
        // tall rectangle: y range widened instead
        c.set_view((0, 0, 101, 201), (0.0, 10.0), (0.0, 10.0), true);
        assert_eq!(c.to_px(0.0, -5.0), (0.0, 200.0));
        assert_eq!(c.to_px(10.0, 15.0), (100.0, 0.0));
        // without equal_aspect the ranges are kept
        c.set_view((0, 0, 101, 201), (0.0, 10.0), (0.0, 10.0), false);
        assert_eq!(c.to_px(10.0, 10.0), (100.0, 0.0));
    }

    #[test]
    fn line_pixels() {
        let mut c = grid();
        c.line((2.0, 3.0), (7.0, 3.0), RED);
        assert_eq!(inked(&c), (2..=7).map(|x| (x, 6)).collect::<Vec<_>>());
        let mut c = grid();
        c.line((4.0, 4.0), (0.0, 0.0), RED);
        let mut want: Vec<_> = (0..=4).map(|i| (i, 9 - i)).collect();
        want.sort_by_key(|&(x, y)| (y, x));
        assert_eq!(inked(&c), want);
        let mut c = grid();
        c.line((1.0, 1.0), (5.0, 3.0), RED); // shallow slope: one pixel per column
        assert_eq!(inked(&c).len(), 5);
        assert_eq!(c.image().get_pixel(1, 8).0, RED);
        assert_eq!(c.image().get_pixel(5, 6).0, RED);
    }

    #[test]
    fn lines_are_clipped_in_f64() {
        let mut c = grid();
        c.line((-1e12, -1e12), (1e12, 1e12), RED);
        let want: Vec<_> = (0..=9).map(|y| (9 - y, y)).collect();
        assert_eq!(inked(&c), want);
        // Ends near f64::MAX pin a slanted line down only to ~1e292, but nothing overflows.
        let mut c = grid();
        c.line((-f64::MAX, -f64::MAX), (f64::MAX, f64::MAX), RED);
        assert!((1..=20).contains(&inked(&c).len()));
        let mut c = grid();
        c.line((-f64::MAX, 2.0), (f64::MAX, 2.0), RED);
        assert_eq!(inked(&c), (0..20).map(|x| (x, 7)).collect::<Vec<_>>());
        let mut c = grid();
        c.line((30.0, 0.0), (40.0, 9.0), RED);
        c.line((-5.0, -5.0), (25.0, -1.0), RED);
        assert!(inked(&c).is_empty());
    }

    #[test]
    fn dots_circles_and_rects() {
        let mut c = grid();
        c.dot((5.2, 4.9), 0.0, RED);
        assert_eq!(inked(&c), [(5, 4)]);
        let mut c = grid();
        c.dot((10.0, 5.0), 2.0, RED);
        assert_eq!(inked(&c).len(), 21);
        let mut c = grid();
        c.circle((9.0, 4.0), 3.0, RED);
        let px = inked(&c);
        assert!(px.contains(&(12, 5)) && px.contains(&(6, 5)) && px.contains(&(9, 2)));
        assert!(!px.contains(&(9, 5)));
        let mut c = grid();
        c.rect_px(1, 1, 4, 3, RED, false);
        assert_eq!(inked(&c).len(), 10);
        c.rect_px(1, 1, 4, 3, RED, true);
        assert_eq!(inked(&c).len(), 12);
    }

    #[test]
    fn text_width_and_extent() {
        assert_eq!(Canvas::text_width("", 3), 0);
        assert_eq!(Canvas::text_width("a", 1), 5);
        assert_eq!(Canvas::text_width("abc", 2), 34);
        assert_eq!(Canvas::text_width("10 µm", 1), 29);
        assert_eq!(Canvas::text_width("x", 0), 5);
        let mut c = Canvas::new(60, 20);
        let w = c.text_px(3, 2, "Ag,", 1, BLACK);
        assert_eq!(w, 17);
        let px = inked(&c);
        assert!(!px.is_empty());
        assert!(px
            .iter()
            .all(|&(x, y)| (3..20).contains(&x) && (2..10).contains(&y)));
        assert!(px.iter().any(|&(_, y)| y == 9)); // descenders of 'g' and ','
        let mut c = Canvas::new(60, 20);
        c.text_px(0, 0, "I", 2, BLACK);
        assert_eq!(c.image().get_pixel(4, 0).0, BLACK); // top bar of 'I' is columns 1..=3
        assert_eq!(c.image().get_pixel(1, 1).0, WHITE);
    }

    #[test]
    fn heatmap_colours() {
        let mut c = Canvas::new(4, 2);
        c.heatmap_px((0, 0, 4, 2), &[0.0, 2.0, f64::NAN, 1.0], 2, 2, 1.0);
        let at = |x, y| c.image().get_pixel(x, y).0;
        assert_eq!(at(0, 0), INFERNO[0]);
        assert_eq!(at(1, 0), INFERNO[0]);
        assert_eq!(at(2, 0), INFERNO[10]);
        assert_eq!(at(0, 1), INFERNO[0]);
        assert_eq!(at(3, 1), INFERNO[10]);
        let mut c = Canvas::new(2, 1);
        c.heatmap_px((0, 0, 2, 1), &[1.0, 2.0], 2, 1, 0.0); // auto max = 2
        assert_eq!(c.image().get_pixel(0, 0).0, INFERNO[5]);
    }

    #[test]
    fn hostile_input_does_not_panic() {
        let mut c = Canvas::new(0, 0);
        assert_eq!(c.image().dimensions(), (1, 1));
        c = Canvas::new(50, 40);
        let nan = f64::NAN;
        c.set_view((0, 0, 0, 0), (nan, nan), (f64::INFINITY, 1.0), true);
        c.set_view((10, 10, 30, 20), (0.0, 1.0), (0.0, 1.0), false);
        let before = c.image().clone();
        c.line((nan, 0.0), (1.0, 1.0), RED);
        c.line((0.0, 0.0), (f64::INFINITY, 1.0), RED);
        c.dot((nan, 0.5), 3.0, RED);
        c.dot((1e308, 0.5), f64::INFINITY, RED);
        c.circle((nan, 0.0), 1.0, RED);
        c.circle((0.5, 0.5), nan, RED);
        c.polyline(&[(0.0, 0.0), (nan, nan)], RED);
        assert_eq!(c.image(), &before);
        c.dot((0.5, 0.5), nan, RED);
        c.circle((0.5, 0.5), 1e300, RED);
        c.polyline(&[(0.0, 0.0), (nan, 1.0), (1.0, 1.0), (1.0, 0.0)], RED);
        c.rect_px(i32::MIN, i32::MAX, u32::MAX, u32::MAX, RED, true);
        c.rect_px(i32::MAX, i32::MIN, u32::MAX, 3, RED, false);
        c.text_px(i32::MAX, -5, "overflow", u32::MAX, RED);
        c.text_px(-40, 5, "é\n\t\u{1F600}", 1, RED);
        c.heatmap_px((40, 30, u32::MAX, u32::MAX), &[1.0; 4], 2, 2, nan);
        c.heatmap_px((0, 0, 10, 10), &[1.0; 3], 2, 2, 1.0);
        c.heatmap_px((0, 0, 10, 10), &[], usize::MAX, 2, 1.0);
        c.set_view(
            (0, 0, u32::MAX, u32::MAX),
            (-1e308, 1e308),
            (1e-320, 2e-320),
            true,
        );
        c.axes("x", "y");
        c.set_view((5, 5, 2, 2), (0.0, 1e-300), (1e300, -1e300), false);
        c.axes("x", "y");
        c.line((0.0, 0.0), (1.0, 1.0), RED);
        c.title("a very long title that does not fit at all, not even at scale one");
        c.title("");
    }

    #[test]
    fn axes_draw_frame_and_labels() {
        let mut c = Canvas::new(300, 200);
        c.set_view((60, 40, 200, 120), (-1.0, 1.0), (0.0, 5.0), false);
        c.axes("x (mm)", "y (mm)");
        let img = c.image();
        // frame one pixel outside the rectangle, plot area left blank
        assert!(
            (59..=260).all(|x| img.get_pixel(x, 39).0 == BLACK && img.get_pixel(x, 160).0 == BLACK)
        );
        assert!(
            (39..=160).all(|y| img.get_pixel(59, y).0 == BLACK && img.get_pixel(260, y).0 == BLACK)
        );
        assert!((61..259).all(|x| (41..159).all(|y| img.get_pixel(x, y).0 == WHITE)));
        // tick at x = 0 (pixel 159.5 -> 160) below the frame, and some label ink below it
        assert_eq!(img.get_pixel(160, 164).0, BLACK);
        assert!((167..175).any(|y| (150..170).any(|x| img.get_pixel(x, y).0 == BLACK)));
    }

    #[test]
    fn save_png_round_trip_and_failure() {
        let dir = std::env::temp_dir().join(format!("tolray-plot-test-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        let mut c = Canvas::new(37, 23);
        c.line((0.0, 0.0), (1.0, 1.0), RED);
        c.text_px(2, 2, "Hi", 1, PALETTE[0]);
        let path = dir.join("out.png");
        c.save_png(&path).unwrap();
        c.save_png(&path).unwrap(); // overwriting works too
        let back = image::open(&path).unwrap().to_rgb8();
        assert_eq!(&back, c.image());
        let names: Vec<_> = fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["out.png"]);

        let missing = dir.join("missing");
        let bad = missing.join("out.png");
        assert!(c.save_png(&bad).is_err());
        assert!(!bad.exists() && !missing.exists());
        assert!(c.save_png(Path::new("")).is_err());
        let names: Vec<_> = fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["out.png"]);
        fs::remove_dir_all(&dir).unwrap();
    }
}
