//! Image files in and out: decoding with limits and EXIF orientation, encoding by extension
//! (`outputs` writes the bytes).

use super::bounded_read;
use super::error::{shown, FileError};
use crate::stack::image::{Image, Sample};
use image::metadata::Orientation;
use image::{DynamicImage, ImageDecoder, ImageFormat};
use std::fs;
use std::io::{BufRead, BufReader, Cursor, Read, Seek, SeekFrom};
use std::path::Path;

type Result<T> = std::result::Result<T, FileError>;

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
            Decoded::U8(i) => (i.width(), i.height()),
            Decoded::U16(i) => (i.width(), i.height()),
        }
    }
}

/// What a decoder may allocate besides the pixels: ICC profiles, text chunks, strip buffers. A
/// camera's ICC profile is a few KiB; a PNG whose iCCP chunk inflates to hundreds of MiB has it
/// dropped (the png crate stops inflating at this limit) while its header is read.
const ANCILLARY_BYTES: u64 = 16 << 20;

/// A frame's header: enough to plan the memory of a stack before any frame is decoded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Header {
    pub width: usize,
    pub height: usize,
    /// 1 for gray, 3 for colour (alpha is dropped).
    pub channels: usize,
    /// 1 for 8-bit samples, 2 for 16-bit.
    pub sample_bytes: usize,
}

/// Reads a frame's header only (for JPEG: the file up to its end-of-image marker), with the
/// same checks as [`load`].
pub fn probe(path: &Path) -> Result<Header> {
    let mut decoder = open_decoder(path)?;
    header(path, &mut decoder)
}

/// Decodes a JPEG, PNG or TIFF file; gray stays 1 channel, anything else becomes RGB. The file
/// must be a regular file ([`bounded_read`]); the decoder may allocate the pixels its header
/// declares (at most [`MAX_PIXELS`]) and [`ANCILLARY_BYTES`] more.
pub fn load(path: &Path) -> Result<Decoded> {
    let mut decoder = open_decoder(path)?;
    header(path, &mut decoder)?;
    let (width, height) = decoder.dimensions();
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(width);
    limits.max_image_height = Some(height);
    limits.max_alloc = Some(decoder.total_bytes().saturating_add(ANCILLARY_BYTES));
    let corrupt = |e: image::ImageError| FileError::Truncated {
        path: shown(path),
        reason: e.to_string(),
    };
    decoder.set_limits(limits).map_err(corrupt)?;
    // Phones store portrait shots as landscape pixels plus an EXIF orientation: the frames are
    // turned upright here, so a stack mixing orientations still registers, and the output's
    // copy of the reference's EXIF says upright (`exif_upright`).
    let orientation = decoder.orientation().unwrap_or(Orientation::NoTransforms);
    let mut img = DynamicImage::from_decoder(decoder).map_err(corrupt)?;
    img.apply_orientation(orientation);
    Ok(from_dynamic(img))
}

/// The header's geometry as the frame will be loaded (turned upright by its EXIF orientation, so
/// a stack mixing stored orientations compares as it fuses), refused when focusd cannot fuse it
/// faithfully.
fn header(path: &Path, decoder: &mut impl ImageDecoder) -> Result<Header> {
    let (w, h) = decoder.dimensions();
    if w as u64 * h as u64 > MAX_PIXELS {
        return Err(FileError::TooLarge {
            path: shown(path),
            width: w,
            height: h,
            limit: MAX_PIXELS,
        });
    }
    let color = decoder.color_type();
    let sample_bytes = usize::from(color.bytes_per_pixel() / color.channel_count());
    if sample_bytes > 2 {
        return Err(FileError::FloatSamples {
            path: shown(path),
            color,
        });
    }
    let turned = matches!(
        decoder.orientation(),
        Ok(Orientation::Rotate90
            | Orientation::Rotate270
            | Orientation::Rotate90FlipH
            | Orientation::Rotate270FlipH)
    );
    let (w, h) = if turned { (h, w) } else { (w, h) };
    Ok(Header {
        width: w as usize,
        height: h as usize,
        channels: if color.has_color() { 3 } else { 1 },
        sample_bytes,
    })
}

/// A decoder over the file with its header read under [`ANCILLARY_BYTES`].
fn open_decoder(path: &Path) -> Result<impl ImageDecoder> {
    let cannot_read = |error| FileError::Read {
        path: shown(path),
        error,
    };
    let file = bounded_read::open(path).map_err(|error| FileError::Open {
        path: shown(path),
        error,
    })?;
    let mut file = BufReader::new(file);
    let start = file.fill_buf().map_err(cannot_read)?;
    if start.starts_with(b"II\x2b\0") || start.starts_with(b"MM\0\x2b") {
        return Err(FileError::BigTiff { path: shown(path) });
    }
    let format = image::guess_format(start)
        .ok()
        .filter(|f| matches!(f, ImageFormat::Jpeg | ImageFormat::Png | ImageFormat::Tiff))
        .ok_or_else(|| FileError::NotAnImage { path: shown(path) })?;
    let source = match format {
        // The JPEG decoder reads its whole input first: it gets the file up to its
        // end-of-image marker, so trailing bytes are never read.
        ImageFormat::Jpeg => Source::Memory(Cursor::new(jpeg_until_end(path, file)?)),
        ImageFormat::Tiff => {
            single_page(path)?;
            Source::File(file)
        }
        _ => Source::File(file),
    };
    let mut reader = image::ImageReader::with_format(source, format);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(ANCILLARY_BYTES);
    reader.limits(limits);
    reader.into_decoder().map_err(|e| unsupported(path, e))
}

/// A multipage TIFF's first page is often a thumbnail: fusing it silently would be wrong.
fn single_page(path: &Path) -> Result<()> {
    let file = bounded_read::open(path).map_err(|error| FileError::ReadFile {
        path: shown(path),
        error,
    })?;
    let tiff =
        tiff::decoder::Decoder::new(BufReader::new(file)).map_err(|e| unsupported(path, e))?;
    if tiff.more_images() {
        return Err(FileError::Multipage { path: shown(path) });
    }
    Ok(())
}

/// `path: corrupt or unsupported image: REASON`.
fn unsupported(path: &Path, reason: impl std::fmt::Display) -> FileError {
    FileError::Unsupported {
        path: shown(path),
        reason: reason.to_string(),
    }
}

/// The JPEG file from its start to its end-of-image marker, read no further. The decoder fills
/// a truncated file's missing rows with grey without an error, so a file that ends before the
/// marker is refused here. The marker segments are walked to the first start-of-scan (skipping
/// APP segments, whose EXIF thumbnails hold markers of their own); after it FF D9 can only be the
/// marker, since scan data escapes FF as FF 00. The frame header (SOF) bounds what may follow:
/// compressed data several times the size of its raw pixels is not a photograph.
fn jpeg_until_end(path: &Path, mut file: impl BufRead) -> Result<Vec<u8>> {
    let truncated = || FileError::Truncated {
        path: shown(path),
        reason: "the JPEG data ends before its end-of-image marker".into(),
    };
    let cannot_read = |error| FileError::Read {
        path: shown(path),
        error,
    };
    let mut out = Vec::new();
    let next = |file: &mut dyn BufRead, out: &mut Vec<u8>| -> Result<u8> {
        let mut b = [0u8];
        file.read_exact(&mut b).map_err(|e| match e.kind() {
            std::io::ErrorKind::UnexpectedEof => truncated(),
            _ => cannot_read(e),
        })?;
        out.push(b[0]);
        Ok(b[0])
    };
    if (next(&mut file, &mut out)?, next(&mut file, &mut out)?) != (0xFF, 0xD8) {
        return Err(unsupported(path, "no JPEG start-of-image marker"));
    }
    // Before the frame header is known: the segments ahead of it (EXIF, ICC, thumbnails).
    let mut cap = ANCILLARY_BYTES as usize;
    loop {
        if next(&mut file, &mut out)? != 0xFF {
            return Err(unsupported(path, "JPEG marker expected"));
        }
        let mut marker = next(&mut file, &mut out)?;
        while marker == 0xFF {
            marker = next(&mut file, &mut out)?;
        }
        if marker == 0xD9 {
            return Err(unsupported(path, "JPEG ends before any image data"));
        }
        let len = u16::from_be_bytes([next(&mut file, &mut out)?, next(&mut file, &mut out)?]);
        let start = out.len();
        let body = usize::from(len).saturating_sub(2);
        if out.len() + body > cap {
            return Err(unsupported(path, format!("JPEG headers over {cap} bytes")));
        }
        out.resize(start + body, 0);
        file.read_exact(&mut out[start..])
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::UnexpectedEof => truncated(),
                _ => cannot_read(e),
            })?;
        // SOF0..SOF15 except DHT (C4), JPG (C8) and DAC (CC): precision, height, width,
        // components.
        if (0xC0..=0xCF).contains(&marker) && ![0xC4, 0xC8, 0xCC].contains(&marker) {
            let &[_, h0, h1, w0, w1, c, ..] = &out[start..] else {
                return Err(truncated());
            };
            let samples = usize::from(u16::from_be_bytes([h0, h1]))
                * usize::from(u16::from_be_bytes([w0, w1]))
                * usize::from(c);
            cap = cap.saturating_add(samples.saturating_mul(4));
        }
        if marker == 0xDA {
            break;
        }
    }
    // The scan data, in the reader's own chunks, to the first FF D9.
    let mut ff = false;
    loop {
        let buf = file.fill_buf().map_err(cannot_read)?;
        if buf.is_empty() {
            return Err(truncated());
        }
        let end = if ff && buf[0] == 0xD9 {
            Some(1)
        } else {
            buf.windows(2)
                .position(|w| w == [0xFF, 0xD9])
                .map(|i| i + 2)
        };
        let take = end.unwrap_or(buf.len());
        out.extend_from_slice(&buf[..take]);
        ff = buf[take - 1] == 0xFF;
        file.consume(take);
        if end.is_some() {
            return Ok(out);
        }
        if out.len() > cap {
            return Err(unsupported(
                path,
                format!("over {cap} bytes of JPEG data without an end-of-image marker"),
            ));
        }
    }
}

/// Where a decoder reads from: the file itself, or (JPEG) the bytes read up to its end marker.
enum Source {
    File(BufReader<fs::File>),
    Memory(Cursor<Vec<u8>>),
}

impl Read for Source {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Source::File(r) => r.read(buf),
            Source::Memory(r) => r.read(buf),
        }
    }
}

impl BufRead for Source {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        match self {
            Source::File(r) => r.fill_buf(),
            Source::Memory(r) => r.fill_buf(),
        }
    }

    fn consume(&mut self, n: usize) {
        match self {
            Source::File(r) => r.consume(n),
            Source::Memory(r) => r.consume(n),
        }
    }
}

impl Seek for Source {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        match self {
            Source::File(r) => r.seek(pos),
            Source::Memory(r) => r.seek(pos),
        }
    }
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
    Ok(if img.channels() == 3 {
        img
    } else {
        Image::from_fn(img.width(), img.height(), 3, |x, y, _| img.at(x, y, 0))
    })
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
        _ => Err(FileError::UnknownExtension {
            path: shown(path),
            ext,
        }),
    }
}

/// Encodes to `format`; JPEG is 8-bit only, so 16-bit images are reduced for it.
pub fn encode<T: Sample>(img: &Image<T>, format: ImageFormat, quality: u8) -> Result<Vec<u8>> {
    if format == ImageFormat::Jpeg {
        return jpeg(img, quality);
    }
    let (w, h) = (img.width() as u32, img.height() as u32);
    let dynamic = if T::MAX > 255.0 {
        let data: Vec<u16> = img.convert::<u16>().into_data();
        match img.channels() {
            1 => DynamicImage::ImageLuma16(image::ImageBuffer::from_raw(w, h, data).unwrap()),
            _ => DynamicImage::ImageRgb16(image::ImageBuffer::from_raw(w, h, data).unwrap()),
        }
    } else {
        let data: Vec<u8> = img.convert::<u8>().into_data();
        match img.channels() {
            1 => DynamicImage::ImageLuma8(image::ImageBuffer::from_raw(w, h, data).unwrap()),
            _ => DynamicImage::ImageRgb8(image::ImageBuffer::from_raw(w, h, data).unwrap()),
        }
    };
    let mut buf = std::io::Cursor::new(Vec::new());
    dynamic.write_to(&mut buf, format)?;
    Ok(buf.into_inner())
}

/// Baseline JPEG at `quality`, chroma at full resolution (4:4:4). Through `jpeg-encoder` rather
/// than `image`'s own encoder: its SIMD path is about twice as fast at the same size and
/// quality.
fn jpeg<T: Sample>(img: &Image<T>, quality: u8) -> Result<Vec<u8>> {
    let side = |v: usize| u16::try_from(v).ok().filter(|&v| v > 0);
    let (Some(w), Some(h)) = (side(img.width()), side(img.height())) else {
        return Err(FileError::JpegSize {
            width: img.width(),
            height: img.height(),
        });
    };
    let colour = match img.channels() {
        1 => jpeg_encoder::ColorType::Luma,
        _ => jpeg_encoder::ColorType::Rgb,
    };
    let mut out = Vec::new();
    let mut enc = jpeg_encoder::Encoder::new(&mut out, quality);
    enc.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_4_4);
    enc.encode(img.convert::<u8>().data(), w, h, colour)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Columns alternating red and blue a pixel apart keep their colours: chroma subsampled
    /// 2:1, as in 4:2:0, would mix both into purple.
    #[test]
    fn jpeg_keeps_colour_at_full_resolution() {
        let img = Image::<u8>::from_fn(32, 16, 3, |x, _, c| match (x % 2, c) {
            (0, 0) | (1, 2) => 255,
            _ => 0,
        });
        let bytes = encode(&img, ImageFormat::Jpeg, 95).expect("encodes");
        let back = image::load_from_memory(&bytes).expect("decodes").to_rgb8();
        let worst = back
            .enumerate_pixels()
            .map(|(x, y, p)| {
                (0..3)
                    .map(|c| p[c].abs_diff(img.at(x as usize, y as usize, c)))
                    .max()
                    .unwrap_or(0)
            })
            .max()
            .unwrap_or(0);
        assert!(worst < 64, "a channel off by {worst}");
    }

    /// A side past what a JPEG header can hold is refused by name, with what to write instead.
    #[test]
    fn jpeg_names_its_size_limit() {
        let img = Image::<u8>::new(70_000, 1, 1);
        let e = encode(&img, ImageFormat::Jpeg, 90).expect_err("too wide for JPEG");
        let e = e.to_string();
        assert!(
            e.contains("65535") && e.contains("70000x1") && e.contains(".png"),
            "{e}"
        );
        let png = encode(&img, ImageFormat::Png, 90).expect("PNG takes it");
        assert!(!png.is_empty());
    }
}
