//! The dead-leaves texture (ISO/TS 19567-2 texture-loss chart): occluding disks of random colour
//! whose radii have density ∝ r⁻³, which makes the picture scale invariant with a 1/f² power
//! spectrum, like natural images. The built-in, infinite and deterministic training source.

use super::{srgb_to_linear, Image};
use crate::error::Result;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Dead-leaves settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeadLeaves {
    /// Smallest disk radius, pixels.
    pub r_min_px: f32,
    /// Largest disk radius, pixels.
    pub r_max_px: f32,
    /// Amplitude of each disk's linear shading across its radius (linear units), a mild texture.
    pub texture: f32,
}

impl Default for DeadLeaves {
    fn default() -> Self {
        DeadLeaves {
            r_min_px: 3.0,
            r_max_px: 200.0,
            texture: 0.08,
        }
    }
}

/// Most disks drawn for one image; what is still uncovered then takes the background.
const MAX_DISKS: usize = 1 << 20;

impl DeadLeaves {
    /// A `w x h` dead-leaves image, deterministic per (`seed`, `stream`). Disks are painted front
    /// to back (the first disk is on top), each edge pixel antialiased by 4 x 4 supersampling, until
    /// every pixel is covered.
    ///
    /// # Errors
    /// [`crate::ErrorKind::Argument`] for an empty or oversized image.
    pub fn generate(&self, w: usize, h: usize, seed: u64, stream: u64) -> Result<Image> {
        let mut img = Image::new(w, h)?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(stream);
        let n = w * h;
        // Transmission left per pixel: 1 uncovered, 0 covered by disks in front.
        let mut rem = vec![1f32; n];
        let mut open = n;
        let (a, b) = (
            self.r_min_px.max(0.1).powi(-2),
            self.r_max_px.max(self.r_min_px.max(0.1)).powi(-2),
        );
        let margin = self.r_max_px;
        for _ in 0..MAX_DISKS {
            if open == 0 {
                break;
            }
            let u: f32 = rng.random();
            let r = (a - u * (a - b)).powf(-0.5);
            let cx = rng.random::<f32>() * (w as f32 + 2.0 * margin) - margin;
            let cy = rng.random::<f32>() * (h as f32 + 2.0 * margin) - margin;
            let col: [f32; 3] = std::array::from_fn(|_| srgb_to_linear(rng.random::<f32>()));
            let ang = rng.random::<f32>() * std::f32::consts::TAU;
            let amp = self.texture * (rng.random::<f32>() - 0.5) * 2.0;
            let (gx, gy) = (amp * ang.cos() / r, amp * ang.sin() / r);
            let x0 = (cx - r - 1.0).floor().max(0.0) as usize;
            let y0 = (cy - r - 1.0).floor().max(0.0) as usize;
            let x1 = ((cx + r + 1.0).ceil().max(0.0) as usize).min(w);
            let y1 = ((cy + r + 1.0).ceil().max(0.0) as usize).min(h);
            for py in y0..y1 {
                for px in x0..x1 {
                    let i = py * w + px;
                    if rem[i] == 0.0 {
                        continue;
                    }
                    let (dx, dy) = (px as f32 + 0.5 - cx, py as f32 + 0.5 - cy);
                    let d = (dx * dx + dy * dy).sqrt();
                    let cover = if d <= r - 0.75 {
                        1.0
                    } else if d >= r + 0.75 {
                        0.0
                    } else {
                        let mut k = 0;
                        for sy in 0..4 {
                            for sx in 0..4 {
                                let (ex, ey) =
                                    (dx + (sx as f32 - 1.5) / 4.0, dy + (sy as f32 - 1.5) / 4.0);
                                k += (ex * ex + ey * ey <= r * r) as u32;
                            }
                        }
                        k as f32 / 16.0
                    };
                    if cover == 0.0 {
                        continue;
                    }
                    let shade = dx * gx + dy * gy;
                    let t = rem[i] * cover;
                    for (c, &cc) in col.iter().enumerate() {
                        img.data[c * n + i] += t * (cc + shade).clamp(0.0, 1.0);
                    }
                    rem[i] = if cover >= 1.0 {
                        0.0
                    } else {
                        rem[i] * (1.0 - cover)
                    };
                    if rem[i] < 1e-3 {
                        rem[i] = 0.0;
                        open -= 1;
                    }
                }
            }
        }
        for (i, &t) in rem.iter().enumerate() {
            for c in 0..3 {
                img.data[c * n + i] += t * 0.18;
            }
        }
        Ok(img)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_covered_and_varied() {
        let d = DeadLeaves::default();
        let a = d.generate(96, 64, 3, 7).unwrap();
        assert_eq!(a, d.generate(96, 64, 3, 7).unwrap());
        assert_ne!(a, d.generate(96, 64, 3, 8).unwrap());
        assert!(a.data.iter().all(|v| (0.0..=1.0).contains(v)));
        // Many distinct colours (many disks), and a picture that is not flat.
        let mean = a.data.iter().sum::<f32>() / a.data.len() as f32;
        let var = a.data.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / a.data.len() as f32;
        assert!(var > 0.01, "variance {var}");
    }
}
