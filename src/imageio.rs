//! Image files in and out: decoding with limits and EXIF orientation, encoding by extension,
//! atomic writes.

use crate::stack::image::{Image, Sample};
use anyhow::{anyhow, bail, Context, Result};
use image::metadata::Orientation;
use image::{DynamicImage, ImageDecoder, ImageFormat};
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Refuse headers that claim more than this many pixels before allocating (decompression bombs).
pub const MAX_PIXELS: u64 = 200_000_000;

/// A decoded frame at its native depth.
pub enum Decoded {
    U8(Image<u8>),
    U16(Image<u16>),
}

impl Decoded {
    pub fn dimensions(&self) -> (usize, usize) {
        match self {
            Decoded::U8(i) => (i.width, i.height),
            Decoded::U16(i) => (i.width, i.height),
        }
    }
}

/// Decodes a JPEG, PNG or TIFF file; gray stays 1 channel, anything else becomes RGB.
pub fn load(path: &Path) -> Result<Decoded> {
    let name = path.display();
    let reader = image::ImageReader::open(path)
        .with_context(|| format!("{name}: cannot open"))?
        .with_guessed_format()
        .with_context(|| format!("{name}: cannot read"))?;
    if reader.format().is_none() {
        bail!("{name}: not a JPEG, PNG or TIFF image");
    }
    let (w, h) = reader
        .into_dimensions()
        .map_err(|e| anyhow!("{name}: corrupt or unsupported image: {e}"))?;
    if w as u64 * h as u64 > MAX_PIXELS {
        bail!("{name}: {w}x{h} is larger than the {MAX_PIXELS}-pixel limit");
    }
    let mut reader = image::ImageReader::open(path)
        .with_context(|| format!("{name}: cannot open"))?
        .with_guessed_format()
        .with_context(|| format!("{name}: cannot read"))?;
    if reader.format() == Some(ImageFormat::Jpeg) {
        let bytes = fs::read(path).with_context(|| format!("{name}: cannot read"))?;
        if !jpeg_complete(&bytes) {
            bail!("{name}: corrupt or truncated image: the JPEG data ends before its end-of-image marker");
        }
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(w);
    limits.max_image_height = Some(h);
    limits.max_alloc = Some(MAX_PIXELS * 8);
    reader.limits(limits);
    let corrupt = |e| anyhow!("{name}: corrupt or truncated image: {e}");
    let mut decoder = reader.into_decoder().map_err(corrupt)?;
    if decoder.total_bytes() > MAX_PIXELS * 8 {
        bail!("{name}: {w}x{h} is larger than the {MAX_PIXELS}-pixel limit");
    }
    // Phones store portrait shots as landscape pixels plus an EXIF orientation: the frames are
    // turned upright here, so a stack mixing orientations still registers, and the output's
    // copy of the reference's EXIF says upright (`exif_upright`).
    let orientation = decoder.orientation().unwrap_or(Orientation::NoTransforms);
    let mut img = DynamicImage::from_decoder(decoder).map_err(corrupt)?;
    img.apply_orientation(orientation);
    Ok(from_dynamic(img))
}

/// Sets the Orientation tag of an EXIF block (a TIFF structure) to 1, upright, in place; a
/// block without one, or one that does not parse, is left as it is.
pub fn exif_upright(exif: &mut [u8]) {
    let big = match exif.get(..4) {
        Some(b"MM\0*") => true,
        Some(b"II*\0") => false,
        _ => return,
    };
    let u16_at = |b: &[u8], i: usize| {
        b.get(i..i + 2).map(|v| {
            let v = [v[0], v[1]];
            if big {
                u16::from_be_bytes(v)
            } else {
                u16::from_le_bytes(v)
            }
        })
    };
    let Some(ifd) = exif.get(4..8).map(|v| {
        let v = [v[0], v[1], v[2], v[3]];
        (if big {
            u32::from_be_bytes(v)
        } else {
            u32::from_le_bytes(v)
        }) as usize
    }) else {
        return;
    };
    let Some(entries) = u16_at(exif, ifd) else {
        return;
    };
    for k in 0..entries as usize {
        let e = ifd + 2 + 12 * k;
        // Tag 0x0112 Orientation, type 3 SHORT, count 1: the value sits in the entry.
        if u16_at(exif, e) == Some(0x0112) && u16_at(exif, e + 2) == Some(3) {
            let one = if big {
                1u16.to_be_bytes()
            } else {
                1u16.to_le_bytes()
            };
            if let Some(v) = exif.get_mut(e + 8..e + 10) {
                v.copy_from_slice(&one);
            }
            return;
        }
    }
}

/// Decodes any supported file as 8-bit RGB (replayed frames).
pub fn load_rgb8(path: &Path) -> Result<Image<u8>> {
    let img = match load(path)? {
        Decoded::U8(i) => i,
        Decoded::U16(i) => i.convert(),
    };
    Ok(if img.channels == 3 {
        img
    } else {
        Image::from_fn(img.width, img.height, 3, |x, y, _| img.at(x, y, 0))
    })
}

/// Whether a JPEG's entropy-coded data is followed by its end-of-image marker. The decoder
/// fills a truncated file's missing rows with grey without an error, so this is checked
/// first: the marker segments are walked to the first start-of-scan (skipping APP segments,
/// whose EXIF thumbnails hold markers of their own), and after it FF D9 can only be the
/// marker, since scan data escapes FF as FF 00.
fn jpeg_complete(b: &[u8]) -> bool {
    if !b.starts_with(&[0xFF, 0xD8]) {
        return false;
    }
    let mut i = 2;
    while i + 4 <= b.len() {
        if b[i] != 0xFF {
            return false;
        }
        let marker = b[i + 1];
        if marker == 0xFF {
            i += 1;
            continue;
        }
        let len = usize::from(u16::from_be_bytes([b[i + 2], b[i + 3]]));
        if marker == 0xDA {
            return b[i + 2..].windows(2).any(|w| w == [0xFF, 0xD9]);
        }
        i += 2 + len;
    }
    false
}

fn from_dynamic(img: DynamicImage) -> Decoded {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let gray = !img.color().has_color();
    let sixteen = img.color().bytes_per_pixel() / img.color().channel_count() > 1;
    match (sixteen, gray) {
        (false, true) => Decoded::U8(Image::from_vec(w, h, 1, img.into_luma8().into_raw())),
        (false, false) => Decoded::U8(Image::from_vec(w, h, 3, img.into_rgb8().into_raw())),
        (true, true) => Decoded::U16(Image::from_vec(w, h, 1, img.into_luma16().into_raw())),
        (true, false) => Decoded::U16(Image::from_vec(w, h, 3, img.into_rgb16().into_raw())),
    }
}

/// The output format named by a path's extension.
pub fn format_for(path: &Path) -> Result<ImageFormat> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    match ext.as_str() {
        "jpg" | "jpeg" => Ok(ImageFormat::Jpeg),
        "png" => Ok(ImageFormat::Png),
        "tif" | "tiff" => Ok(ImageFormat::Tiff),
        _ => bail!(
            "{}: unknown output extension {ext:?}; use .jpg, .png or .tif",
            path.display()
        ),
    }
}

/// Encodes to `format`; JPEG is 8-bit only, so 16-bit images are reduced for it.
pub fn encode<T: Sample>(img: &Image<T>, format: ImageFormat, quality: u8) -> Result<Vec<u8>> {
    let (w, h) = (img.width as u32, img.height as u32);
    let dynamic = if T::MAX > 255.0 && format != ImageFormat::Jpeg {
        let data: Vec<u16> = img.convert::<u16>().data;
        match img.channels {
            1 => DynamicImage::ImageLuma16(image::ImageBuffer::from_raw(w, h, data).unwrap()),
            _ => DynamicImage::ImageRgb16(image::ImageBuffer::from_raw(w, h, data).unwrap()),
        }
    } else {
        let data: Vec<u8> = img.convert::<u8>().data;
        match img.channels {
            1 => DynamicImage::ImageLuma8(image::ImageBuffer::from_raw(w, h, data).unwrap()),
            _ => DynamicImage::ImageRgb8(image::ImageBuffer::from_raw(w, h, data).unwrap()),
        }
    };
    let mut buf = std::io::Cursor::new(Vec::new());
    if format == ImageFormat::Jpeg {
        let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, quality);
        dynamic.write_with_encoder(enc)?;
    } else {
        dynamic.write_to(&mut buf, format)?;
    }
    Ok(buf.into_inner())
}

/// The temporary file [`write_atomic`] writes `path` through, beside it: `.NAME.PID.tmp`.
pub fn temp_path(path: &Path) -> Result<PathBuf> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let file_name = path
        .file_name()
        .ok_or_else(|| anyhow!("{}: not a file path", path.display()))?;
    Ok(dir.join(format!(
        ".{}.{}.tmp",
        file_name.to_string_lossy(),
        std::process::id()
    )))
}

/// Writes through a temporary file in the same directory and renames it into place, so a crash
/// or a full disk never leaves a partial file under the final name.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = temp_path(path)?;
    // A stale temporary file (a crash) or a link planted under its name is removed, and the
    // new one is created exclusively, so the write never follows a link out of the directory.
    let _ = fs::remove_file(&tmp);
    let result = (|| {
        let mut f = fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = fs::remove_file(&tmp);
        bail!("{}: cannot write: {e}", path.display());
    }
    Ok(())
}

/// Encodes by `path`'s extension and writes atomically.
pub fn save<T: Sample>(img: &Image<T>, path: &Path, quality: u8) -> Result<()> {
    let bytes = encode(img, format_for(path)?, quality)?;
    write_atomic(path, &bytes)
}
