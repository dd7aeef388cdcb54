//! Images for deep optics: planar RGB in linear light inside, sRGB only at the file boundary
//! (PNG/JPEG read and PNG written as sRGB; EXR written linear) and for metrics.
//!
//! Layout: `data[c * w * h + row * w + col]`, row 0 at the top of the picture (+y on the sensor),
//! column 0 at the left (-x), channels R, G, B.

pub mod deadleaves;
pub mod metrics;
pub mod render;
pub mod source;

use crate::error::{Error, ErrorKind, Result};
use crate::files::write_atomic;
use std::path::Path;

/// Most pixels an image may have (2^28, a 16384² picture; 3 GB as f32 RGB).
pub const MAX_PIXELS: usize = 1 << 28;

/// A planar RGB image in linear light, values nominally in [0, 1].
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// `3 · width · height` values, channel-major, row-major, row 0 at the top.
    pub data: Vec<f32>,
}

/// sRGB-encoded value to linear light (IEC 61966-2-1).
#[inline]
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear light to its sRGB encoding (IEC 61966-2-1); negative values map to themselves / 12.92
/// scaled, as the standard's linear segment extended.
#[inline]
pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

impl Image {
    /// A black `width x height` image.
    ///
    /// # Errors
    /// [`ErrorKind::Argument`] for an empty image or one of more than [`MAX_PIXELS`] pixels.
    pub fn new(width: usize, height: usize) -> Result<Image> {
        let n = width.saturating_mul(height);
        if n == 0 || n > MAX_PIXELS {
            return Err(Error::argument(format!(
                "image {width}x{height}: give 1 to {MAX_PIXELS} pixels"
            )));
        }
        Ok(Image {
            width,
            height,
            data: vec![0.0; 3 * n],
        })
    }

    /// Channel `c` (0 = R, 1 = G, 2 = B).
    pub fn plane(&self, c: usize) -> &[f32] {
        let n = self.width * self.height;
        &self.data[c * n..(c + 1) * n]
    }

    /// Channel `c`, mutable.
    pub fn plane_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.width * self.height;
        &mut self.data[c * n..(c + 1) * n]
    }

    /// The `w x h` block whose top-left pixel is `(x0, y0)`.
    ///
    /// # Errors
    /// [`ErrorKind::Argument`] when the block leaves the image or is empty.
    pub fn crop(&self, x0: usize, y0: usize, w: usize, h: usize) -> Result<Image> {
        if w == 0 || h == 0 || x0 + w > self.width || y0 + h > self.height {
            return Err(Error::argument(format!(
                "crop {w}x{h} at ({x0}, {y0}) leaves the {}x{} image",
                self.width, self.height
            )));
        }
        let mut out = Image::new(w, h)?;
        for c in 0..3 {
            let src = self.plane(c);
            let dst = out.plane_mut(c);
            for r in 0..h {
                let s = (y0 + r) * self.width + x0;
                dst[r * w..(r + 1) * w].copy_from_slice(&src[s..s + w]);
            }
        }
        Ok(out)
    }

    /// The image mirrored left to right.
    pub fn flip_h(&self) -> Image {
        let mut out = self.clone();
        let w = self.width;
        for row in out.data.chunks_mut(w) {
            row.reverse();
        }
        out
    }

    /// The sRGB encoding of the image, clamped to [0, 1] (what metrics compare).
    pub fn to_srgb(&self) -> Image {
        Image {
            width: self.width,
            height: self.height,
            data: self
                .data
                .iter()
                .map(|&v| linear_to_srgb(v.clamp(0.0, 1.0)))
                .collect(),
        }
    }

    /// Decodes a PNG or JPEG held in memory (8 or 16 bits, grey expanded to RGB, alpha dropped),
    /// sRGB to linear.
    ///
    /// # Errors
    /// [`ErrorKind::Parse`] when the bytes are not a readable PNG or JPEG.
    pub fn decode(bytes: &[u8]) -> Result<Image> {
        let img = image::load_from_memory(bytes).map_err(|e| {
            Error::new(ErrorKind::Parse, format!("not a readable PNG or JPEG: {e}"))
        })?;
        let rgb = img.to_rgb32f();
        let (w, h) = (rgb.width() as usize, rgb.height() as usize);
        let mut out = Image::new(w, h)?;
        let n = w * h;
        for (i, p) in rgb.pixels().enumerate() {
            for c in 0..3 {
                out.data[c * n + i] = srgb_to_linear(p.0[c]);
            }
        }
        Ok(out)
    }

    /// Reads a PNG or JPEG file (see [`Image::decode`]).
    ///
    /// # Errors
    /// I/O and decoding errors naming the path.
    pub fn load(path: &Path) -> Result<Image> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Image::decode(&bytes).map_err(|e| e.context(path.display()))
    }

    /// The image as an 8-bit sRGB PNG in memory.
    ///
    /// # Errors
    /// [`ErrorKind::Io`] if the encoder fails.
    pub fn encode_png(&self) -> Result<Vec<u8>> {
        let n = self.width * self.height;
        let mut buf = vec![0u8; 3 * n];
        for i in 0..n {
            for c in 0..3 {
                let v = linear_to_srgb(self.data[c * n + i].clamp(0.0, 1.0));
                buf[3 * i + c] = (v * 255.0 + 0.5) as u8;
            }
        }
        let mut out = Vec::new();
        image::codecs::png::PngEncoder::new(&mut out)
            .write_image(
                &buf,
                self.width as u32,
                self.height as u32,
                image::ExtendedColorType::Rgb8,
            )
            .map_err(|e| Error::new(ErrorKind::Io, format!("PNG encoding: {e}")))?;
        Ok(out)
    }

    /// Writes an 8-bit sRGB PNG atomically.
    ///
    /// # Errors
    /// I/O errors naming the path.
    pub fn save_png(&self, path: &Path) -> Result<()> {
        write_atomic(
            path,
            &self.encode_png().map_err(|e| e.context(path.display()))?,
        )
    }

    /// Writes the linear values as a 32-bit float RGB OpenEXR file, atomically.
    ///
    /// # Errors
    /// I/O errors naming the path.
    pub fn save_exr(&self, path: &Path) -> Result<()> {
        crate::figures::save_exr_rgb(path, self.width, self.height, &self.data)
    }
}

use image::ImageEncoder;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trip_and_crop() {
        for k in 0..=100 {
            let v = k as f32 / 100.0;
            assert!((linear_to_srgb(srgb_to_linear(v)) - v).abs() < 1e-6);
        }
        let mut img = Image::new(4, 3).unwrap();
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = i as f32;
        }
        let c = img.crop(1, 1, 2, 2).unwrap();
        assert_eq!(c.plane(0), &[5.0, 6.0, 9.0, 10.0]);
        assert_eq!(c.plane(2), &[29.0, 30.0, 33.0, 34.0]);
        assert!(img.crop(3, 0, 2, 1).is_err());
        assert_eq!(img.flip_h().plane(0)[..4], [3.0, 2.0, 1.0, 0.0]);
        let png = img.to_srgb().encode_png().unwrap();
        assert!(Image::decode(&png).is_ok());
        assert!(Image::decode(b"not an image").is_err());
        assert!(Image::new(0, 5).is_err());
    }
}
