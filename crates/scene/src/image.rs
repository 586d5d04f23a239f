//! Images as float RGB in [0, 1], `H × W × 3`, row-major: PNG (8 or 16 bit; grey,
//! grey+alpha, RGB, RGBA, palette) and baseline/progressive JPEG in, 8-bit PNG out.
//!
//! Values are stored as they are in the file (no gamma change): 3DGS renders in the
//! colour space of its training images. An alpha channel is returned separately so
//! the caller can composite over its background.

use crate::{atomic, Error, Result};
use std::path::Path;

/// A float RGB image, `data.len() == width * height * 3`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
    /// Per-pixel alpha in [0, 1] when the file had an alpha channel.
    pub alpha: Option<Vec<f32>>,
}

impl RgbImage {
    /// Composites the alpha channel (if any) over `background` and drops it.
    pub fn composite(mut self, background: [f32; 3]) -> Self {
        if let Some(alpha) = self.alpha.take() {
            for (px, a) in self.data.chunks_exact_mut(3).zip(alpha) {
                for (v, b) in px.iter_mut().zip(background) {
                    *v = *v * a + b * (1.0 - a);
                }
            }
        }
        self
    }
}

/// Extensions tried, in this order, for an image named without one (the readers go by
/// content, not by extension).
pub const EXTENSIONS: &[&str] = &["png", "jpg", "jpeg", "PNG", "JPG", "JPEG"];

/// `stem_path` with the first of [`EXTENSIONS`] appended (`a/b` → `a/b.png`, `a/b.c` →
/// `a/b.c.png`) that names a file.
pub fn find_with_extension(stem_path: &Path) -> Option<std::path::PathBuf> {
    EXTENSIONS
        .iter()
        .map(|e| {
            let mut s = stem_path.as_os_str().to_os_string();
            s.push(".");
            s.push(e);
            std::path::PathBuf::from(s)
        })
        .find(|p| p.is_file())
}

/// Whether `path` ends in one of [`EXTENSIONS`] (any case).
pub fn has_image_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| EXTENSIONS.iter().any(|x| x.eq_ignore_ascii_case(e)))
}

/// Deflate packs at most 1032 bytes into one (a 258-byte match coded in 2 bits), so a
/// PNG whose header needs more raw scanline bytes than 1032 times the file size cannot
/// hold its pixels: refused before allocating for them.
const DEFLATE_MAX_RATIO: usize = 1032;

/// A JPEG spends at least one bit per 8×8 luma block (its DC code), at most 512 pixels a
/// byte; twice that is allowed. The decoder fills missing data with grey, so without
/// this a few hundred damaged bytes claiming 32767×32767 would allocate gigabytes.
const JPEG_MAX_PIXELS_PER_BYTE: usize = 1024;

/// Reads a PNG or JPEG file (by content, not extension).
pub fn read(path: &Path) -> Result<RgbImage> {
    let bytes = atomic::read(path)?;
    decode(&bytes, path)
}

/// Decodes PNG or JPEG bytes; `path` is only used in messages.
pub fn decode(bytes: &[u8], path: &Path) -> Result<RgbImage> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        decode_png(bytes, path)
    } else if bytes.starts_with(&[0xFF, 0xD8]) {
        decode_jpeg(bytes, path)
    } else {
        Err(Error::format(path, "not a PNG or JPEG image"))
    }
}

fn decode_png(bytes: &[u8], path: &Path) -> Result<RgbImage> {
    let err = |e: png::DecodingError| Error::format(path, format!("bad PNG: {e}"));
    let mut dec = png::Decoder::new(bytes);
    dec.set_transformations(png::Transformations::EXPAND);
    let mut reader = dec.read_info().map_err(err)?;
    let (w, h) = (reader.info().width as usize, reader.info().height as usize);
    check_size(w, h, path)?;
    if reader.info().raw_bytes() > bytes.len().saturating_mul(DEFLATE_MAX_RATIO) {
        return Err(too_small(w, h, bytes.len(), path));
    }
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let frame = reader.next_frame(&mut buf).map_err(err)?;
    let (ct, depth) = (frame.color_type, frame.bit_depth);
    let channels = match ct {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => return Err(Error::format(path, "palette PNG was not expanded")),
    };
    let samples: Vec<f32> = match depth {
        png::BitDepth::Sixteen => buf[..frame.buffer_size()]
            .chunks_exact(2)
            .map(|c| u16::from_be_bytes([c[0], c[1]]) as f32 / 65535.0)
            .collect(),
        png::BitDepth::Eight => buf[..frame.buffer_size()].iter().map(|&v| v as f32 / 255.0).collect(),
        d => return Err(Error::format(path, format!("unsupported PNG bit depth {d:?}"))),
    };
    from_samples(w, h, channels, &samples, path)
}

fn decode_jpeg(bytes: &[u8], path: &Path) -> Result<RgbImage> {
    let mut dec = jpeg_decoder::Decoder::new(bytes);
    dec.read_info().map_err(|e| Error::format(path, format!("bad JPEG: {e}")))?;
    let info = dec.info().ok_or_else(|| Error::format(path, "bad JPEG: no header"))?;
    let (w, h) = (info.width as usize, info.height as usize);
    check_size(w, h, path)?;
    if w * h > bytes.len().saturating_mul(JPEG_MAX_PIXELS_PER_BYTE) {
        return Err(too_small(w, h, bytes.len(), path));
    }
    let px = dec.decode().map_err(|e| Error::format(path, format!("bad JPEG: {e}")))?;
    let (channels, samples): (usize, Vec<f32>) = match info.pixel_format {
        jpeg_decoder::PixelFormat::L8 => (1, px.iter().map(|&v| v as f32 / 255.0).collect()),
        jpeg_decoder::PixelFormat::L16 => {
            (1, px.chunks_exact(2).map(|c| u16::from_be_bytes([c[0], c[1]]) as f32 / 65535.0).collect())
        }
        jpeg_decoder::PixelFormat::RGB24 => (3, px.iter().map(|&v| v as f32 / 255.0).collect()),
        jpeg_decoder::PixelFormat::CMYK32 => {
            let rgb = px
                .chunks_exact(4)
                .flat_map(|c| {
                    let k = 1.0 - c[3] as f32 / 255.0;
                    [0, 1, 2].map(|i| (1.0 - c[i] as f32 / 255.0) * k)
                })
                .collect();
            (3, rgb)
        }
    };
    from_samples(w, h, channels, &samples, path)
}

fn check_size(w: usize, h: usize, path: &Path) -> Result<()> {
    if w == 0 || h == 0 {
        return Err(Error::format(path, format!("image has zero size {w}x{h}")));
    }
    // The one cap for image files and cameras.
    crate::camera::check_image_size(w as u64, h as u64).map_err(|m| Error::format(path, m))
}

fn too_small(w: usize, h: usize, len: usize, path: &Path) -> Error {
    Error::format(
        path,
        format!("image header says {w}x{h} pixels, more than its {len} bytes can hold (damaged file)"),
    )
}

fn from_samples(w: usize, h: usize, channels: usize, s: &[f32], path: &Path) -> Result<RgbImage> {
    if s.len() < w * h * channels {
        return Err(Error::format(path, "image data is truncated"));
    }
    let mut data = Vec::with_capacity(w * h * 3);
    let mut alpha = (channels == 2 || channels == 4).then(|| Vec::with_capacity(w * h));
    for px in s.chunks_exact(channels).take(w * h) {
        match channels {
            1 | 2 => data.extend_from_slice(&[px[0]; 3]),
            _ => data.extend_from_slice(&px[..3]),
        }
        if let Some(a) = alpha.as_mut() {
            a.push(px[channels - 1]);
        }
    }
    Ok(RgbImage { width: w, height: h, data, alpha })
}

/// Quantises `[0, 1]` floats to 8 bits (clamped, rounded; NaN becomes 0).
pub fn to_u8(v: f32) -> u8 {
    if v.is_nan() {
        0
    } else {
        (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
    }
}

/// Writes an 8-bit RGB PNG atomically from `H × W × 3` floats in [0, 1].
pub fn write_png(path: &Path, width: usize, height: usize, rgb: &[f32]) -> Result<()> {
    assert_eq!(rgb.len(), width * height * 3, "image buffer does not match its size");
    let bytes: Vec<u8> = rgb.iter().map(|&v| to_u8(v)).collect();
    atomic::write_with(path, |w| {
        let mut enc = png::Encoder::new(w, width as u32, height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().map_err(std::io::Error::other)?;
        writer.write_image_data(&bytes).map_err(std::io::Error::other)?;
        writer.finish().map_err(std::io::Error::other)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    const MAX_SIDE: usize = crate::camera::MAX_IMAGE_SIDE as usize;
    const MAX_PIXELS: usize = crate::camera::MAX_IMAGE_PIXELS as usize;

    #[test]
    fn sizes_are_checked_per_side_and_in_total() {
        let p = Path::new("s.png");
        assert!(check_size(MAX_SIDE, MAX_PIXELS / MAX_SIDE, p).is_ok());
        let e = check_size(MAX_SIDE, MAX_PIXELS / MAX_SIDE + 1, p).unwrap_err().to_string();
        assert!(e.contains("s.png") && e.contains("32768x4097") && e.contains("128 million"), "{e}");
        assert!(check_size(MAX_SIDE + 1, 1, p).unwrap_err().to_string().contains("a side"));
        assert!(check_size(0, 5, p).unwrap_err().to_string().contains("zero size"));
    }

    #[test]
    fn extensions_are_appended_in_order_and_matched_in_any_case() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        assert_eq!(find_with_extension(&d.join("a")), None);
        std::fs::write(d.join("a.JPG"), b"x").unwrap();
        assert_eq!(find_with_extension(&d.join("a")), Some(d.join("a.JPG")));
        std::fs::write(d.join("a.png"), b"x").unwrap();
        assert_eq!(find_with_extension(&d.join("a")), Some(d.join("a.png")));
        // Appended, not replaced: `b.v1` looks for `b.v1.png`.
        std::fs::write(d.join("b.png"), b"x").unwrap();
        assert_eq!(find_with_extension(&d.join("b.v1")), None);
        // A folder with an image name is not an image.
        std::fs::create_dir(d.join("c.png")).unwrap();
        assert_eq!(find_with_extension(&d.join("c")), None);
        assert!(has_image_extension(Path::new("x/y.JpEg")) && has_image_extension(Path::new("y.png")));
        assert!(!has_image_extension(Path::new("y.npy")) && !has_image_extension(Path::new("png")));
    }

    fn png_bytes(w: u32, h: u32, ct: png::ColorType, depth: png::BitDepth, data: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, w, h);
            enc.set_color(ct);
            enc.set_depth(depth);
            let mut wr = enc.write_header().unwrap();
            wr.write_image_data(data).unwrap();
        }
        out
    }

    #[test]
    fn png_round_trip_is_exact_at_8_bits() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        let rgb: Vec<f32> = (0..2 * 3 * 3).map(|i| (i * 15) as f32 / 255.0).collect();
        write_png(&p, 3, 2, &rgb).unwrap();
        let img = read(&p).unwrap();
        assert_eq!((img.width, img.height), (3, 2));
        for (a, b) in img.data.iter().zip(&rgb) {
            assert!((a - b).abs() < 1e-6);
        }
        assert!(img.alpha.is_none());
    }

    #[test]
    fn grey_rgba_and_16_bit_are_converted() {
        let p = Path::new("x.png");
        let g =
            decode(&png_bytes(2, 1, png::ColorType::Grayscale, png::BitDepth::Eight, &[0, 255]), p).unwrap();
        assert_eq!(g.data, vec![0.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
        let rgba = png_bytes(1, 1, png::ColorType::Rgba, png::BitDepth::Eight, &[255, 0, 0, 51]);
        let img = decode(&rgba, p).unwrap().composite([0.0, 0.0, 1.0]);
        let want = [0.2, 0.0, 0.8];
        for (a, b) in img.data.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{:?}", img.data);
        }
        let s16 =
            png_bytes(1, 1, png::ColorType::Rgb, png::BitDepth::Sixteen, &[0xFF, 0xFF, 0x80, 0x00, 0, 0]);
        let img = decode(&s16, p).unwrap();
        assert!((img.data[1] - 32768.0 / 65535.0).abs() < 1e-6);
    }

    #[test]
    fn garbage_and_truncation_are_errors_naming_the_file() {
        let p = Path::new("bad.png");
        let e = decode(b"hello", p).unwrap_err().to_string();
        assert!(e.contains("bad.png") && e.contains("not a PNG"), "{e}");
        let good = png_bytes(4, 4, png::ColorType::Rgb, png::BitDepth::Eight, &[7; 48]);
        let e = decode(&good[..good.len() - 20], p).unwrap_err().to_string();
        assert!(e.contains("bad.png"), "{e}");
        let e = decode(&[0xFF, 0xD8, 0xFF, 0x00], Path::new("bad.jpg")).unwrap_err().to_string();
        assert!(e.contains("bad.jpg") && e.contains("JPEG"), "{e}");
    }

    /// Found by the `image` fuzz target: 68 bytes of PNG claiming 32768x32768 RGBA16
    /// made the decoder allocate 8 GB before reading the data, and a damaged 646-byte
    /// JPEG claiming 32767x32767 allocated 3 GB (the decoder fills missing data with grey).
    /// Those sizes are now over the pixel cap too, so the byte bounds are tested with
    /// sizes under it (8192x8192 and 8000x8000).
    #[test]
    fn tiny_files_claiming_huge_sizes_are_refused_before_allocating() {
        let png = png_bytes(1, 1, png::ColorType::Rgba, png::BitDepth::Sixteen, &[0; 8]);
        let mut lying = png.clone();
        let mut claim = |w: u32, h: u32| {
            lying[16..20].copy_from_slice(&w.to_be_bytes()); // IHDR width, height
            lying[20..24].copy_from_slice(&h.to_be_bytes());
            let crc = crc32(&lying[12..29]);
            lying[29..33].copy_from_slice(&crc.to_be_bytes());
            decode(&lying, Path::new("big.png")).unwrap_err().to_string()
        };
        let e = claim(8192, 8192);
        assert!(e.contains("big.png") && e.contains("8192x8192") && e.contains("bytes can hold"), "{e}");
        let e = claim(32768, 32768);
        assert!(e.contains("big.png") && e.contains("32768x32768"), "{e}");
        assert!(decode(&png, Path::new("ok.png")).is_ok(), "the same file with its true size reads");
        // A flat 1-bit 2048x2048 PNG packs 526 KB of scanlines at well over 50:1: far
        // from the deflate bound, it still reads.
        let flat = png_bytes(2048, 2048, png::ColorType::Grayscale, png::BitDepth::One, &vec![0; 256 * 2048]);
        assert!(flat.len() * 50 < 2048 * 257, "{}", flat.len());
        assert_eq!(decode(&flat, Path::new("flat.png")).unwrap().width, 2048);

        let jpeg = include_bytes!("../testdata/huge_size.jpg");
        let e = decode(jpeg, Path::new("big.jpg")).unwrap_err().to_string();
        assert!(e.contains("big.jpg") && e.contains("32767x32767"), "{e}");
        // The same file claiming 8000x8000 (SOF0: marker, length, precision, height, width).
        let mut smaller = jpeg.to_vec();
        let sof = smaller.windows(2).position(|w| w == [0xFF, 0xC0]).expect("baseline JPEG");
        smaller[sof + 5..sof + 9].copy_from_slice(&[0x1F, 0x40, 0x1F, 0x40]);
        let e = decode(&smaller, Path::new("big.jpg")).unwrap_err().to_string();
        assert!(e.contains("big.jpg") && e.contains("8000x8000") && e.contains("bytes can hold"), "{e}");
        let ok = include_bytes!("../testdata/baseline_8x8.jpg");
        assert_eq!(decode(ok, Path::new("ok.jpg")).unwrap().width, 8);
    }

    /// CRC-32 (IEEE) of a PNG chunk's type and data.
    fn crc32(b: &[u8]) -> u32 {
        let mut c = !0u32;
        for &x in b {
            c ^= x as u32;
            for _ in 0..8 {
                c = if c & 1 == 1 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            }
        }
        !c
    }
}
