//! The decoder's file, `decoder.bin`: every parameter exactly, after a JSON header of the
//! decoder's settings, checked before anything is allocated when read.

use super::{Decoder, DecoderKind};
use crate::error::{Error, ErrorKind, Result};
use crate::files::write_atomic;
use std::path::Path;

/// Writes a decoder as `decoder.bin`: the magic `TOLRDEC1`, a little-endian `u32` header length,
/// a JSON header (the decoder's settings and parameter count), then every parameter as a
/// little-endian `f64` (exact).
///
/// # Errors
/// I/O errors naming the path.
pub fn save_decoder(d: &Decoder, path: &Path) -> Result<()> {
    write_atomic(path, &decoder_to_bytes(d))
}

/// The bytes [`save_decoder`] writes (read back by [`decoder_from_bytes`]).
///
/// # Examples
/// ```
/// use tolray::decoder::{Decoder, DecoderKind};
/// use tolray::decoder::file::{decoder_from_bytes, decoder_to_bytes};
/// let psfs = vec![1.0 / 9.0; 3 * 9];
/// let d = Decoder::new(DecoderKind::Wiener, 1, 3, &psfs, 0.01, 1, 0)?;
/// let back = decoder_from_bytes(&decoder_to_bytes(&d), "d.bin")?;
/// assert_eq!(back.params(), d.params());
/// # Ok::<(), tolray::Error>(())
/// ```
pub fn decoder_to_bytes(d: &Decoder) -> Vec<u8> {
    let header = serde_json::json!({
        "kind": d.kind, "grid": d.grid, "ks": d.ks, "unet_width": d.unet_width,
        "n_params": d.params().len(), "dtype": "f64le",
    })
    .to_string();
    let mut bytes = Vec::with_capacity(12 + header.len() + 8 * d.params().len());
    bytes.extend_from_slice(b"TOLRDEC1");
    bytes.extend_from_slice(&(header.len() as u32).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in d.params() {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    bytes
}

/// Reads a decoder written by [`save_decoder`].
///
/// # Errors
/// [`ErrorKind::Io`], or [`ErrorKind::Parse`] naming the path and what is wrong.
pub fn load_decoder(path: &Path) -> Result<Decoder> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decoder_from_bytes(&bytes, &path.display().to_string())
}

/// Reads the bytes of a `decoder.bin` ([`save_decoder`]'s format); `name` (a path) prefixes
/// errors. The header's sizes are checked against the parameter count before anything is
/// allocated, so a damaged file cannot ask for more memory than it holds.
///
/// # Errors
/// [`ErrorKind::Parse`] naming `name` and what is wrong (magic, header, sizes, non-finite
/// parameters).
///
/// # Examples
/// ```
/// use tolray::decoder::file::decoder_from_bytes;
/// let e = decoder_from_bytes(b"TOLRDEC1\x02\0\0\0{}", "d.bin").unwrap_err();
/// assert!(e.message().starts_with("d.bin: kind"), "{}", e.message());
/// ```
pub fn decoder_from_bytes(bytes: &[u8], name: &str) -> Result<Decoder> {
    let bad = |m: &str| Error::new(ErrorKind::Parse, format!("{name}: {m}"));
    if bytes.len() < 12 || &bytes[..8] != b"TOLRDEC1" {
        return Err(bad("not a tolray decoder (no TOLRDEC1 magic)"));
    }
    let hl = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize;
    let header = bytes
        .get(12..12usize.saturating_add(hl))
        .ok_or_else(|| bad("truncated header"))?;
    let h: serde_json::Value =
        serde_json::from_slice(header).map_err(|e| bad(&format!("header: {e}")))?;
    let get = |k: &str| {
        h.get(k)
            .and_then(|v| v.as_u64())
            .ok_or_else(|| bad(&format!("header lacks {k}")))
    };
    let kind: DecoderKind =
        serde_json::from_value(h["kind"].clone()).map_err(|e| bad(&format!("kind: {e}")))?;
    let (grid, ks, width, n) = (
        get("grid")?,
        get("ks")?,
        get("unet_width")?,
        get("n_params")?,
    );
    let data = &bytes[12 + hl..];
    if data.len() as u64 != n.saturating_mul(8) {
        return Err(bad(&format!(
            "{} parameter bytes, {} expected",
            data.len(),
            n.saturating_mul(8)
        )));
    }
    if !(1..=64).contains(&grid) || ks % 2 == 0 || !(3..=255).contains(&ks) {
        return Err(bad(&format!("grid {grid} or kernel {ks} out of range")));
    }
    let (grid, ks) = (grid as usize, ks as usize);
    let width = usize::try_from(width).unwrap_or(usize::MAX);
    let expected = Decoder::param_count(kind, grid, ks, width);
    if expected != Some(n as usize) {
        return Err(bad(&format!(
            "{n} parameters, but a {kind:?} decoder of grid {grid}, kernel {ks} and U-Net width \
             {width} has {}",
            expected.map_or("too many".into(), |e| e.to_string())
        )));
    }
    let ks2 = ks * ks;
    let mut d = Decoder::new(
        kind,
        grid,
        ks,
        &vec![0f32; grid * grid * 3 * ks2],
        0.01,
        width,
        0,
    )
    .map_err(|e| e.context(name))?;
    let params: Vec<f64> = data
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
        .collect();
    d.set_params(&params).map_err(|e| e.context(name))?;
    Ok(d)
}
