//! Where training crops come from: the built-in dead-leaves texture (the default, infinite) or a
//! folder of photographs (PNG/JPEG, e.g. DIV2K) read once into memory, from which each crop is a
//! random block with random horizontal and vertical flips. Either way a crop is deterministic per
//! (seed, stream), so a training run repeats exactly whatever the thread count.

use super::deadleaves::DeadLeaves;
use super::Image;
use crate::error::{Error, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A training-image source. It serializes as the folder it was read from (`null` for dead
/// leaves); a deserialized folder source holds no pixels until [`TrainImages::reload`].
///
/// ```
/// use tolray::image::source::TrainImages;
/// let src = TrainImages::default();
/// let a = src.crop(40, 7, 3).unwrap();
/// assert_eq!((a.width, a.height), (40, 40));
/// assert_eq!(a, src.crop(40, 7, 3).unwrap()); // deterministic per (seed, stream)
/// ```
#[derive(Clone, Debug, Default)]
pub struct TrainImages {
    dir: Option<PathBuf>,
    photos: Arc<Vec<(String, Image)>>,
}

impl PartialEq for TrainImages {
    fn eq(&self, other: &Self) -> bool {
        self.dir == other.dir
    }
}

impl Serialize for TrainImages {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        self.dir.serialize(s)
    }
}

impl<'de> Deserialize<'de> for TrainImages {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        Ok(TrainImages {
            dir: Option::<PathBuf>::deserialize(d)?,
            photos: Arc::new(Vec::new()),
        })
    }
}

/// The PNG and JPEG files of `dir`, sorted by name.
///
/// # Errors
/// I/O errors naming the folder; a folder without images.
pub fn image_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(Error::argument(format!(
            "{}: no PNG or JPEG image in this folder",
            dir.display()
        )));
    }
    Ok(files)
}

impl TrainImages {
    /// Every PNG or JPEG image of `dir`, linearized, each at least `min_side` pixels on both
    /// sides (the training crop plus its PSF halo).
    ///
    /// # Errors
    /// I/O and decoding errors naming the file; a folder without images; an image smaller than
    /// `min_side`.
    pub fn from_dir(dir: &Path, min_side: usize) -> Result<TrainImages> {
        let mut photos = Vec::new();
        for f in image_files(dir)? {
            let img = Image::load(&f)?;
            if img.width < min_side || img.height < min_side {
                return Err(Error::argument(format!(
                    "{}: {}x{} is smaller than the {min_side}x{min_side} training crop with its \
                     PSF halo",
                    f.display(),
                    img.width,
                    img.height
                )));
            }
            let name = f
                .file_name()
                .map_or(String::new(), |n| n.to_string_lossy().into());
            photos.push((name, img));
        }
        Ok(TrainImages {
            dir: Some(dir.to_path_buf()),
            photos: Arc::new(photos),
        })
    }

    /// The folder, or `None` for dead leaves.
    pub fn dir(&self) -> Option<&Path> {
        self.dir.as_deref()
    }

    /// Reads the folder again (after deserializing); dead leaves stay as they are.
    ///
    /// # Errors
    /// As [`TrainImages::from_dir`].
    pub fn reload(&mut self, min_side: usize) -> Result<()> {
        if let Some(d) = self.dir.clone() {
            *self = TrainImages::from_dir(&d, min_side)?;
        }
        Ok(())
    }

    /// A `side x side` training crop, deterministic per (`seed`, `stream`): a dead-leaves image,
    /// or a random block of a random photograph, flipped left-right and top-bottom with
    /// probability 1/2 each.
    ///
    /// # Errors
    /// A folder source that was deserialized and not reloaded; an oversized crop.
    pub fn crop(&self, side: usize, seed: u64, stream: u64) -> Result<Image> {
        if self.dir.is_none() {
            return DeadLeaves::default().generate(side, side, seed, stream);
        }
        if self.photos.is_empty() {
            return Err(Error::argument(format!(
                "training images of {} are not loaded",
                self.dir.as_deref().unwrap_or(Path::new("")).display()
            )));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7068_6f74_6f73);
        rng.set_stream(stream);
        let (_, img) = &self.photos[rng.random_range(0..self.photos.len())];
        if img.width < side || img.height < side {
            return Err(Error::argument(format!(
                "training crop {side} px is larger than a {}x{} image",
                img.width, img.height
            )));
        }
        let x0 = rng.random_range(0..=img.width - side);
        let y0 = rng.random_range(0..=img.height - side);
        let mut out = img.crop(x0, y0, side, side)?;
        if rng.random::<bool>() {
            out = out.flip_h();
        }
        if rng.random::<bool>() {
            for c in 0..3 {
                let p = out.plane_mut(c);
                for r in 0..side / 2 {
                    let (a, b) = p.split_at_mut((side - 1 - r) * side);
                    a[r * side..(r + 1) * side].swap_with_slice(&mut b[..side]);
                }
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn photo_crops_are_blocks_of_the_photos_and_repeat_per_stream() {
        let dir = std::env::temp_dir().join(format!("tolray-src-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // A 24x20 picture whose pixels are all distinct, so a crop identifies its position.
        let (w, h) = (24, 20);
        let mut img = Image::new(w, h).unwrap();
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = ((i * 37) % 251) as f32 / 251.0;
        }
        img.save_png(&dir.join("a.png")).unwrap();
        std::fs::write(dir.join("notes.txt"), "not an image").unwrap();
        let src = TrainImages::from_dir(&dir, 8).unwrap();
        let img = Image::load(&dir.join("a.png")).unwrap();
        let mut flips = [0usize; 4];
        for s in 0..64 {
            let c = src.crop(8, 5, s).unwrap();
            assert_eq!(c, src.crop(8, 5, s).unwrap());
            // Find the block and the flips that give this crop.
            let mut found = None;
            'search: for y0 in 0..=h - 8 {
                for x0 in 0..=w - 8 {
                    let b = img.crop(x0, y0, 8, 8).unwrap();
                    for f in 0..4 {
                        let mut t = if f & 1 == 1 { b.flip_h() } else { b.clone() };
                        if f & 2 == 2 {
                            for ch in 0..3 {
                                let p = t.plane_mut(ch);
                                let rows: Vec<Vec<f32>> =
                                    p.chunks(8).rev().map(|r| r.to_vec()).collect();
                                p.copy_from_slice(&rows.concat());
                            }
                        }
                        if t == c {
                            found = Some(f);
                            break 'search;
                        }
                    }
                }
            }
            flips[found.expect("a crop is a (flipped) block of the photograph")] += 1;
        }
        assert!(flips.iter().all(|&n| n > 4), "flips {flips:?}");
        assert!(TrainImages::from_dir(&dir, 30).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
