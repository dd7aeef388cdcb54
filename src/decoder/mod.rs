//! Image-reconstruction decoders trained jointly with the lens, written by hand with explicit
//! backward passes (see ARCHITECTURE.md for why no framework): a per-tile Wiener/Tikhonov
//! deconvolution ([`wiener`]) with learned regularization and PSF estimates, optionally followed
//! by a small field-aware U-Net ([`unet`]) that adds a residual correction; and the image loss
//! ([`loss`]).
//!
//! Parameters of every part live in one flat `f64` vector ([`Decoder::params`]) so that one
//! Adam, with a learning rate per group, steps them together with the lens.

mod conv;
pub mod file;
pub mod loss;
pub mod unet;
pub mod wiener;

pub use loss::ImageLossWeights;

use crate::error::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Which decoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DecoderKind {
    /// Per-tile Wiener filters alone.
    Wiener,
    /// A U-Net alone (on the captured image and the field coordinates).
    Unet,
    /// Per-tile Wiener filters, then a U-Net residual (the default).
    WienerUnet,
}

impl DecoderKind {
    /// Parses `wiener`, `unet` or `wiener+unet`.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] naming the text.
    pub fn parse(s: &str) -> Result<DecoderKind> {
        match s {
            "wiener" => Ok(DecoderKind::Wiener),
            "unet" => Ok(DecoderKind::Unet),
            "wiener+unet" => Ok(DecoderKind::WienerUnet),
            _ => Err(Error::argument(format!(
                "decoder \"{s}\": give wiener, unet or wiener+unet"
            ))),
        }
    }
    /// The name [`DecoderKind::parse`] reads: `wiener`, `unet` or `wiener+unet`.
    ///
    /// ```
    /// use tolray::decoder::DecoderKind;
    /// for k in [DecoderKind::Wiener, DecoderKind::Unet, DecoderKind::WienerUnet] {
    ///     assert_eq!(DecoderKind::parse(k.name())?, k);
    /// }
    /// # Ok::<(), tolray::Error>(())
    /// ```
    pub fn name(self) -> &'static str {
        match self {
            DecoderKind::Wiener => "wiener",
            DecoderKind::Unet => "unet",
            DecoderKind::WienerUnet => "wiener+unet",
        }
    }

    /// Whether the decoder has Wiener filters.
    ///
    /// ```
    /// use tolray::decoder::DecoderKind;
    /// assert!(DecoderKind::WienerUnet.has_wiener() && !DecoderKind::Unet.has_wiener());
    /// ```
    pub fn has_wiener(self) -> bool {
        self != DecoderKind::Unet
    }
    /// Whether the decoder has a U-Net.
    ///
    /// ```
    /// use tolray::decoder::DecoderKind;
    /// assert!(DecoderKind::Unet.has_unet() && !DecoderKind::Wiener.has_unet());
    /// ```
    pub fn has_unet(self) -> bool {
        self != DecoderKind::Wiener
    }
}

/// One training or evaluation crop: the captured image `y` (3 x h x w planar, linear), the
/// sharp target `x` (same shape; empty when decoding only), and the PSF tile it was imaged at.
#[derive(Clone, Debug)]
pub struct Crop {
    /// PSF tile (row-major over the grid, row 0 at the top).
    pub tile: usize,
    /// Captured image.
    pub y: Vec<f32>,
    /// Sharp image.
    pub x: Vec<f32>,
    /// Width, pixels.
    pub w: usize,
    /// Height, pixels.
    pub h: usize,
}

/// What one crop of a training batch contributes: its scaled loss, its decoded image, its
/// parameter gradients (U-Net, Wiener; empty without that stage) and dL/dcapture.
struct CropPass {
    loss: f64,
    xhat: Vec<f32>,
    dunet: Vec<f32>,
    dwiener: Vec<f64>,
    dy: Vec<f32>,
}

/// What a training pass over a batch returns.
#[derive(Clone, Debug)]
pub struct BatchOutput {
    /// Mean image loss over the crops.
    pub loss: f64,
    /// PSNR of the decoded crops against the sharp ones (sRGB, pooled MSE), dB.
    pub psnr_db: f64,
    /// dL/dparams of the mean loss.
    pub dparams: Vec<f64>,
    /// dL/dy of the mean loss, per crop.
    pub dy: Vec<Vec<f32>>,
}

/// A decoder: Wiener filters and/or a U-Net, with all parameters in one `f64` vector.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Decoder {
    /// Which parts.
    pub kind: DecoderKind,
    /// PSF grid per side.
    pub grid: usize,
    /// PSF kernel size.
    pub ks: usize,
    /// U-Net width (first-level channels).
    pub unet_width: usize,
    /// Every parameter: the Wiener filters' first, then the U-Net's.
    params: Vec<f64>,
    /// Number of Wiener parameters at the front of `params`.
    n_wiener: usize,
}

/// Input channels of the U-Net: the Wiener output (or the capture), the capture, and the field
/// position of the tile (normalized sensor x and y, constant over a crop).
const UNET_IN: usize = 8;

impl Decoder {
    /// A decoder whose Wiener filters start from `init_psfs` (the lens' RGB PSF map, tile-major,
    /// `grid² · 3 · ks²`) with regularization set for noise `noise_sigma`, and whose U-Net starts
    /// as the identity (zero last layer) with He-initialised weights from `seed`.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for sizes that do not match.
    pub fn new(
        kind: DecoderKind,
        grid: usize,
        ks: usize,
        init_psfs: &[f32],
        noise_sigma: f64,
        unet_width: usize,
        seed: u64,
    ) -> Result<Decoder> {
        let mut params = Vec::new();
        if kind.has_wiener() {
            // Noise-to-signal power: σ² over the variance of natural-image content (~0.05).
            let log_lambda = ((noise_sigma * noise_sigma).max(1e-8) / 0.05).ln();
            let w = wiener::Wiener::new(grid, ks, init_psfs, log_lambda, (1e-3f64).ln())?;
            params.extend_from_slice(&w.params);
        }
        let n_wiener = params.len();
        if kind.has_unet() {
            let u = unet::Unet::new(Self::unet_config(unet_width), seed)?;
            params.extend(u.params.iter().map(|&v| v as f64));
        }
        Ok(Decoder {
            kind,
            grid,
            ks,
            unet_width,
            params,
            n_wiener,
        })
    }

    /// Number of parameters of a decoder of this shape, without building it; `None` for a shape
    /// [`Decoder::new`] refuses or whose count overflows.
    ///
    /// # Examples
    /// ```
    /// use tolray::decoder::{Decoder, DecoderKind};
    /// // 8x8 tiles of RGB 51x51 PSF estimates plus two log weights each.
    /// assert_eq!(Decoder::param_count(DecoderKind::Wiener, 8, 51, 8), Some(64 * 3 * (51 * 51 + 2)));
    /// assert_eq!(Decoder::param_count(DecoderKind::Unet, 8, 51, 0), None);
    /// ```
    pub fn param_count(
        kind: DecoderKind,
        grid: usize,
        ks: usize,
        unet_width: usize,
    ) -> Option<usize> {
        let mut n = 0usize;
        if kind.has_wiener() {
            if grid == 0 || ks.is_multiple_of(2) {
                return None;
            }
            n = grid
                .checked_mul(grid)?
                .checked_mul(3)?
                .checked_mul(ks.checked_mul(ks)?.checked_add(2)?)?;
        }
        if kind.has_unet() {
            n = n.checked_add(unet::param_count(Self::unet_config(unet_width))?)?;
        }
        Some(n)
    }

    fn unet_config(width: usize) -> unet::UnetConfig {
        unet::UnetConfig {
            in_channels: UNET_IN,
            width,
            levels: 3,
        }
    }

    /// Every parameter, Wiener filters first.
    pub fn params(&self) -> &[f64] {
        &self.params
    }

    /// Replaces every parameter.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for a vector of another length or with a non-finite value.
    pub fn set_params(&mut self, p: &[f64]) -> Result<()> {
        if p.len() != self.params.len() || p.iter().any(|v| !v.is_finite()) {
            return Err(Error::argument(format!(
                "decoder parameters: {} values (finite) expected, got {}",
                self.params.len(),
                p.len()
            )));
        }
        // U-Net weights are held in f32: a value past its range would be infinite there.
        if let Some(i) = p[self.n_wiener..]
            .iter()
            .position(|v| v.abs() > f32::MAX as f64)
        {
            return Err(Error::argument(format!(
                "decoder parameter {}: {:e} is outside the range of the U-Net's f32 weights",
                self.n_wiener + i,
                p[self.n_wiener + i]
            )));
        }
        self.params.copy_from_slice(p);
        Ok(())
    }

    /// A learning rate per parameter: `psf` for the Wiener PSF estimates, `reg` for their log
    /// regularization weights, `unet` for the U-Net weights.
    pub fn learning_rates(&self, psf: f64, reg: f64, unet: f64) -> Vec<f64> {
        let mut lr = vec![unet; self.params.len()];
        if self.kind.has_wiener() {
            let w = self.wiener();
            for (i, l) in lr.iter_mut().enumerate().take(self.n_wiener) {
                *l = if w.is_psf_param(i) { psf } else { reg };
            }
        }
        lr
    }

    fn wiener(&self) -> wiener::Wiener {
        wiener::Wiener {
            grid: self.grid,
            ks: self.ks,
            params: self.params[..self.n_wiener].to_vec(),
        }
    }

    fn unet(&self) -> Result<unet::Unet> {
        let mut u = unet::Unet::new(Self::unet_config(self.unet_width), 0)?;
        debug_assert_eq!(
            u.params.len(),
            self.params.len() - self.n_wiener,
            "the U-Net takes every parameter after the Wiener filters"
        );
        for (d, s) in u.params.iter_mut().zip(&self.params[self.n_wiener..]) {
            *d = *s as f32;
        }
        Ok(u)
    }

    /// The U-Net input of a crop: base image, capture, field coordinates of its tile.
    fn unet_input(&self, c: &Crop, base: &[f32]) -> Vec<f32> {
        let n = c.w * c.h;
        let mut v = Vec::with_capacity(UNET_IN * n);
        v.extend_from_slice(base);
        v.extend_from_slice(&c.y);
        let g = self.grid as f32;
        let (row, col) = ((c.tile / self.grid) as f32, (c.tile % self.grid) as f32);
        v.extend(std::iter::repeat_n((2.0 * col + 1.0) / g - 1.0, n));
        v.extend(std::iter::repeat_n(1.0 - (2.0 * row + 1.0) / g, n));
        v
    }

    fn check(&self, crops: &[Crop]) -> Result<(usize, usize)> {
        let first = crops
            .first()
            .ok_or_else(|| Error::argument("a decoder batch needs at least one crop"))?;
        let (w, h) = (first.w, first.h);
        for c in crops {
            if c.w != w || c.h != h || c.y.len() != 3 * w * h || c.tile >= self.grid * self.grid {
                return Err(Error::argument(format!(
                    "decoder batch: crop of tile {} is {}x{} with {} values; all must be {w}x{h} RGB on the {}x{} grid",
                    c.tile, c.w, c.h, c.y.len(), self.grid, self.grid
                )));
            }
        }
        Ok((w, h))
    }

    /// Decodes every crop (forward only).
    ///
    /// # Errors
    /// Mismatched crops; U-Net sizes not divisible by 8; [`crate::ErrorKind::Numerical`] if an
    /// output pixel is not finite (parameters that overflow, as a damaged `decoder.bin` can hold).
    pub fn decode_batch(&self, crops: &[Crop]) -> Result<Vec<Vec<f32>>> {
        let out = self.decode_batch_unchecked(crops)?;
        if let Some((j, _)) = out
            .iter()
            .enumerate()
            .find(|(_, o)| o.iter().any(|v| !v.is_finite()))
        {
            return Err(Error::numerical(format!(
                "the decoder's output for crop {j} (tile {}) is not finite: its parameters \
                 overflow",
                crops[j].tile
            )));
        }
        Ok(out)
    }

    fn decode_batch_unchecked(&self, crops: &[Crop]) -> Result<Vec<Vec<f32>>> {
        let (w, h) = self.check(crops)?;
        let wiener = self.kind.has_wiener().then(|| self.wiener());
        let base: Vec<Vec<f32>> = crops
            .par_iter()
            .map(|c| match &wiener {
                Some(f) => Ok(f.forward_patch(c.tile, &c.y, w, h)?.0),
                None => Ok(c.y.clone()),
            })
            .collect::<Result<_>>()?;
        if !self.kind.has_unet() {
            return Ok(base);
        }
        let u = self.unet()?;
        let mut input = Vec::with_capacity(crops.len() * UNET_IN * w * h);
        for (c, b) in crops.iter().zip(&base) {
            input.extend(self.unet_input(c, b));
        }
        let out = u.infer(&input, crops.len(), h, w)?;
        Ok(base
            .into_iter()
            .enumerate()
            .map(|(j, mut b)| {
                for (v, r) in b.iter_mut().zip(&out[j * 3 * w * h..(j + 1) * 3 * w * h]) {
                    *v += r;
                }
                b
            })
            .collect())
    }

    /// One crop of [`Decoder::train_batch`]: decoded, scored (its loss scaled by `inv`) and
    /// differentiated, its activations freed before it returns.
    fn crop_pass(
        &self,
        c: &Crop,
        (w, h): (usize, usize),
        wiener: Option<&wiener::Wiener>,
        unet: Option<&unet::Unet>,
        inv: f64,
        weights: &ImageLossWeights,
    ) -> Result<CropPass> {
        let m = 3 * w * h;
        let (base, wcache) = match wiener {
            Some(f) => f
                .forward_patch(c.tile, &c.y, w, h)
                .map(|(o, k)| (o, Some(k)))?,
            None => (c.y.clone(), None),
        };
        // The U-Net residual.
        let ucache = unet.map(|u| u.forward_one(&self.unet_input(c, &base), h, w, true));
        let xhat: Vec<f32> = match &ucache {
            Some((out, _)) => base.iter().zip(out).map(|(a, r)| a + r).collect(),
            None => base,
        };
        let (l, mut g) = loss::image_loss(&xhat, &c.x, w, h, weights);
        for v in g.iter_mut() {
            *v *= inv as f32;
        }
        let mut dbase = g.clone();
        let mut dy = unet::written_zeros(m);
        let mut dunet = Vec::new();
        if let (Some(u), Some((_, cache))) = (unet, ucache) {
            dunet = vec![0f32; u.params.len()];
            let di = u.backward_one(&cache, &g, &mut dunet);
            drop(cache);
            for (a, b) in dbase.iter_mut().zip(&di[..m]) {
                *a += b;
            }
            for (a, b) in dy.iter_mut().zip(&di[m..2 * m]) {
                *a += b;
            }
        }
        let mut dwiener = Vec::new();
        match (wiener, &wcache) {
            (Some(f), Some(cache)) => {
                dwiener = vec![0.0; self.n_wiener];
                let mut dyj = unet::written_zeros(m);
                f.backward_patch(c.tile, cache, &dbase, &mut dwiener, &mut dyj);
                for (a, b) in dy.iter_mut().zip(&dyj) {
                    *a += b;
                }
            }
            _ => {
                for (a, v) in dy.iter_mut().zip(&dbase) {
                    *a += v;
                }
            }
        }
        Ok(CropPass {
            loss: l * inv,
            xhat,
            dunet,
            dwiener,
            dy,
        })
    }

    /// Decodes the batch, evaluates the mean image loss against each crop's `x`, and returns its
    /// gradients with respect to the parameters and to each capture.
    ///
    /// # Errors
    /// As [`Decoder::decode_batch`]; crops without a sharp target.
    pub fn train_batch(&self, crops: &[Crop], weights: &ImageLossWeights) -> Result<BatchOutput> {
        let (w, h) = self.check(crops)?;
        if crops.iter().any(|c| c.x.len() != 3 * w * h) {
            return Err(Error::argument(
                "decoder training needs the sharp image of every crop",
            ));
        }
        let n = crops.len();
        let m = 3 * w * h;
        let wiener = self.kind.has_wiener().then(|| self.wiener());
        let unet = match self.kind.has_unet() {
            true => {
                let u = self.unet()?;
                u.check_size(h, w)?;
                Some(u)
            }
            false => None,
        };
        // Each crop through the whole pipeline on its own (Wiener, U-Net residual, loss, U-Net
        // and Wiener backward), so that only the crops in flight hold their activations; the
        // parts are reduced below in crop order (thread-count free).
        let inv = 1.0 / n as f64;
        let parts: Vec<CropPass> = crops
            .par_iter()
            .map(|c| self.crop_pass(c, (w, h), wiener.as_ref(), unet.as_ref(), inv, weights))
            .collect::<Result<_>>()?;
        // The batch loss is the crops' mean.
        let loss: f64 = parts.iter().map(|p| p.loss).sum();
        let mut se = 0.0;
        for (p, c) in parts.iter().zip(crops) {
            for (a, b) in p.xhat.iter().zip(&c.x) {
                let d = crate::image::linear_to_srgb(a.clamp(0.0, 1.0)) as f64
                    - crate::image::linear_to_srgb(b.clamp(0.0, 1.0)) as f64;
                se += d * d;
            }
        }
        let psnr_db = -10.0 * (se / (n * m) as f64).max(1e-20).log10();
        let mut dparams = vec![0.0; self.params.len()];
        if let Some(u) = &unet {
            let mut dp = vec![0f32; u.params.len()];
            for p in &parts {
                for (a, b) in dp.iter_mut().zip(&p.dunet) {
                    *a += b;
                }
            }
            for (d, s) in dparams[self.n_wiener..].iter_mut().zip(&dp) {
                *d += *s as f64;
            }
        }
        if wiener.is_some() {
            for p in &parts {
                for (a, b) in dparams[..self.n_wiener].iter_mut().zip(&p.dwiener) {
                    *a += b;
                }
            }
        }
        let dy = parts.into_iter().map(|p| p.dy).collect();
        Ok(BatchOutput {
            loss,
            psnr_db,
            dparams,
            dy,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::file::decoder_from_bytes;
    use super::*;

    fn bytes(kind: &str, grid: u64, ks: u64, width: u64, n: u64, params: &[f64]) -> Vec<u8> {
        let h = format!(
            r#"{{"kind":"{kind}","grid":{grid},"ks":{ks},"unet_width":{width},"n_params":{n}}}"#
        );
        let mut b = b"TOLRDEC1".to_vec();
        b.extend_from_slice(&(h.len() as u32).to_le_bytes());
        b.extend_from_slice(h.as_bytes());
        for v in params {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b
    }

    /// Found by examples/fuzz.rs: the header's sizes were trusted before the parameter count
    /// was compared, so a damaged file could ask for gigabytes (grid 64, kernel 255) or overflow
    /// the U-Net's channel count; and parameters that overflow decoded to infinite pixels.
    #[test]
    fn damaged_decoder_files_are_refused_and_overflow_is_an_error() {
        let n = Decoder::param_count(DecoderKind::Wiener, 1, 3, 1).unwrap();
        assert_eq!(n, 3 * (9 + 2));
        let ok = vec![0.1; n];
        assert!(decoder_from_bytes(&bytes("wiener", 1, 3, 1, n as u64, &ok), "d").is_ok());
        for (kind, grid, ks, width) in [
            ("wiener", 64, 255, 1),
            ("wiener-unet", 1, 3, 1 << 40),
            ("unet", 1, 3, u64::MAX),
            ("wiener", 2, 3, 1),
        ] {
            let e = decoder_from_bytes(&bytes(kind, grid, ks, width, n as u64, &ok), "d.bin")
                .unwrap_err();
            assert!(e.message().starts_with("d.bin: "), "{}", e.message());
            assert!(e.message().contains("parameters, but"), "{}", e.message());
        }
        // Finite parameters whose filter is not finite: an error, not NaN pixels.
        let mut big = vec![0.0; n];
        big[27..].fill(-1000.0); // λ = μ = 0 and a zero PSF estimate: 0/0
        let d = decoder_from_bytes(&bytes("wiener", 1, 3, 1, n as u64, &big), "d").unwrap();
        let x = vec![0.5f32; 3 * 16 * 16];
        let crop = Crop {
            tile: 0,
            y: x.clone(),
            x,
            w: 16,
            h: 16,
        };
        let e = d.decode_batch(&[crop]).unwrap_err();
        assert_eq!(e.kind(), crate::ErrorKind::Numerical, "{}", e.message());
        // U-Net weights past f32's range are refused when read.
        let nu = Decoder::param_count(DecoderKind::Unet, 1, 3, 1).unwrap();
        let mut w = vec![0.0; nu];
        w[0] = 1e39;
        let e = decoder_from_bytes(&bytes("unet", 1, 3, 1, nu as u64, &w), "d").unwrap_err();
        assert!(e.message().contains("f32"), "{}", e.message());
    }
}
