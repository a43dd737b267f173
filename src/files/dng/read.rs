//! Reading a DNG's raw mosaic as a [`RawFrame`]: uncompressed CFA images of 8 to 16 bits a
//! sample, in strips or tiles, with a 2×2 Bayer pattern. Anything else is refused with the tag
//! and value that rule it out.
//!
//! The `tiff` crate's decoder cannot be used: it refuses a CFA image (PhotometricInterpretation
//! 32803) when it opens the file, before a tag can be read. The file is read whole under a cap
//! and every offset and count is checked against its length, so a hostile file costs at most
//! a few times its own size.

use super::{bayer_order, development_matrix, tag, CFA, D65};
use crate::develop::raw::{self, Packing};
use crate::develop::{RawFrame, IDENTITY};
use crate::files::bounded_read;
use crate::files::error::{shown, FileError};
use crate::files::imageio::{Header, MAX_PIXELS};
use crate::files::orientation::Orientation;
use nalgebra::Matrix3;
use std::collections::BTreeMap;
use std::path::Path;

/// A DNG's raw image and the turns that make it upright.
#[derive(Clone, Debug, PartialEq)]
pub struct DngFrame {
    pub raw: RawFrame,
    pub orientation: Orientation,
}

/// The largest DNG read: a mosaic at the pixel limit in 16-bit samples, with room for
/// previews and metadata.
const FILE_CAP: u64 = MAX_PIXELS * 2 + (64 << 20);

/// Reads and decodes a DNG file (a regular file of at most [`FILE_CAP`] bytes).
pub fn load(path: &Path) -> Result<DngFrame, FileError> {
    let bytes = read(path)?;
    decode(&bytes).map_err(|reason| unsupported(path, reason))
}

/// A DNG's geometry as [`load`] gives it after development (colour, 8 bits, upright), with
/// the same checks but without unpacking the samples.
pub fn probe(path: &Path) -> Result<Header, FileError> {
    let bytes = read(path)?;
    let m = Main::parse(&bytes).map_err(|reason| unsupported(path, reason))?;
    let (w, h) = if m.orientation.quarter_turns() % 2 == 1 {
        (m.height, m.width)
    } else {
        (m.width, m.height)
    };
    Ok(Header {
        width: w,
        height: h,
        channels: 3,
        sample_bytes: 1,
    })
}

fn read(path: &Path) -> Result<Vec<u8>, FileError> {
    bounded_read::read(path, FILE_CAP).map_err(|error| FileError::ReadFile {
        path: shown(path),
        error,
    })
}

fn unsupported(path: &Path, reason: String) -> FileError {
    FileError::Unsupported {
        path: shown(path),
        reason,
    }
}

/// Decodes a DNG in memory; the error says what is wrong or unsupported.
pub fn decode(bytes: &[u8]) -> Parsed<DngFrame> {
    let m = Main::parse(bytes)?;
    Ok(DngFrame {
        raw: m.raw_frame(bytes)?,
        orientation: m.orientation,
    })
}

type Parsed<T> = Result<T, String>;

/// A TIFF's bytes with their byte order.
struct Tiff<'a> {
    data: &'a [u8],
    big_endian: bool,
}

/// One directory entry: its field type, count and where its value's bytes start.
#[derive(Clone, Copy)]
struct Entry {
    typ: u16,
    count: usize,
    at: usize,
}

type Ifd = BTreeMap<u16, Entry>;

/// Bytes a value of each TIFF field type takes (0: a type focusd does not read).
fn type_size(typ: u16) -> usize {
    match typ {
        1 | 2 | 6 | 7 => 1,
        3 | 8 => 2,
        4 | 9 | 11 | 13 => 4,
        5 | 10 | 12 => 8,
        _ => 0,
    }
}

impl Tiff<'_> {
    fn bytes(&self, at: usize, n: usize) -> Parsed<&[u8]> {
        at.checked_add(n)
            .and_then(|end| self.data.get(at..end))
            .ok_or_else(|| format!("truncated: {n} bytes at offset {at} are past the end"))
    }

    fn u16(&self, at: usize) -> Parsed<u16> {
        let b: [u8; 2] = self.bytes(at, 2)?.try_into().expect("2 bytes");
        Ok(if self.big_endian {
            u16::from_be_bytes(b)
        } else {
            u16::from_le_bytes(b)
        })
    }

    fn u32(&self, at: usize) -> Parsed<u32> {
        let b: [u8; 4] = self.bytes(at, 4)?.try_into().expect("4 bytes");
        Ok(if self.big_endian {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        })
    }

    /// The directory at `offset`; entries of types focusd does not read are left out.
    fn ifd(&self, offset: usize) -> Parsed<Ifd> {
        let n = usize::from(self.u16(offset)?);
        let mut ifd = Ifd::new();
        for i in 0..n {
            let e = offset + 2 + 12 * i;
            let (tag, typ) = (self.u16(e)?, self.u16(e + 2)?);
            let count = self.u32(e + 4)? as usize;
            let size = type_size(typ);
            if size == 0 {
                continue;
            }
            let len = size
                .checked_mul(count)
                .ok_or_else(|| format!("tag {tag}: count {count} overflows"))?;
            let at = if len <= 4 {
                e + 8
            } else {
                self.u32(e + 8)? as usize
            };
            self.bytes(at, len).map_err(|_| {
                format!("tag {tag}: its {len}-byte value is past the end of the file")
            })?;
            ifd.insert(tag, Entry { typ, count, at });
        }
        Ok(ifd)
    }

    /// An integer entry's values.
    fn uints(&self, e: Entry, name: &str) -> Parsed<Vec<u64>> {
        (0..e.count)
            .map(|i| match e.typ {
                1 | 7 => Ok(u64::from(self.data[e.at + i])),
                3 => self.u16(e.at + 2 * i).map(u64::from),
                4 | 13 => self.u32(e.at + 4 * i).map(u64::from),
                t => Err(format!(
                    "{name} has field type {t}, not an unsigned integer"
                )),
            })
            .collect()
    }

    /// A numeric entry's values as reals (rationals divided out).
    fn reals(&self, e: Entry, name: &str) -> Parsed<Vec<f64>> {
        (0..e.count)
            .map(|i| match e.typ {
                5 | 10 => {
                    let (n, d) = (self.u32(e.at + 8 * i)?, self.u32(e.at + 8 * i + 4)?);
                    let (n, d) = if e.typ == 10 {
                        (f64::from(n as i32), f64::from(d as i32))
                    } else {
                        (f64::from(n), f64::from(d))
                    };
                    if d == 0.0 {
                        return Err(format!("{name} has a zero denominator"));
                    }
                    Ok(n / d)
                }
                11 => Ok(f64::from(f32::from_bits(self.u32(e.at + 4 * i)?))),
                12 => {
                    let (a, b) = (self.u32(e.at + 8 * i)?, self.u32(e.at + 8 * i + 4)?);
                    let bits = if self.big_endian {
                        u64::from(a) << 32 | u64::from(b)
                    } else {
                        u64::from(b) << 32 | u64::from(a)
                    };
                    Ok(f64::from_bits(bits))
                }
                _ => Ok(self.uints(
                    Entry {
                        count: 1,
                        at: e.at + type_size(e.typ) * i,
                        ..e
                    },
                    name,
                )?[0] as f64),
            })
            .collect()
    }
}

/// Where the samples are: strips of rows, or tiles.
enum Chunks {
    Strips {
        rows: usize,
        offsets: Vec<u64>,
    },
    Tiles {
        width: usize,
        length: usize,
        offsets: Vec<u64>,
    },
}

/// The main (full-resolution raw) image of a DNG, checked.
struct Main {
    big_endian: bool,
    width: usize,
    height: usize,
    bits: u32,
    order: crate::develop::BayerOrder,
    /// The black level of each cell of the 2×2 pattern, row by row.
    black: [f64; 4],
    white: u64,
    matrix: [[f32; 3]; 3],
    /// The white balance gains of AsShotNeutral, where the file has it.
    white_balance: Option<[f32; 3]>,
    orientation: Orientation,
    chunks: Chunks,
}

/// A DNG tag's name, for messages.
fn named(t: u16) -> &'static str {
    match t {
        tag::NEW_SUBFILE_TYPE => "NewSubFileType",
        tag::IMAGE_WIDTH => "ImageWidth",
        tag::IMAGE_LENGTH => "ImageLength",
        tag::BITS_PER_SAMPLE => "BitsPerSample",
        tag::COMPRESSION => "Compression",
        tag::PHOTOMETRIC => "PhotometricInterpretation",
        tag::STRIP_OFFSETS => "StripOffsets",
        tag::ORIENTATION => "Orientation",
        tag::SAMPLES_PER_PIXEL => "SamplesPerPixel",
        tag::ROWS_PER_STRIP => "RowsPerStrip",
        tag::STRIP_BYTE_COUNTS => "StripByteCounts",
        tag::PLANAR_CONFIGURATION => "PlanarConfiguration",
        tag::TILE_WIDTH => "TileWidth",
        tag::TILE_LENGTH => "TileLength",
        tag::TILE_OFFSETS => "TileOffsets",
        tag::TILE_BYTE_COUNTS => "TileByteCounts",
        tag::SUB_IFDS => "SubIFDs",
        tag::SAMPLE_FORMAT => "SampleFormat",
        tag::CFA_REPEAT_PATTERN_DIM => "CFARepeatPatternDim",
        tag::CFA_PATTERN => "CFAPattern",
        tag::DNG_VERSION => "DNGVersion",
        tag::CFA_PLANE_COLOR => "CFAPlaneColor",
        tag::CFA_LAYOUT => "CFALayout",
        tag::LINEARIZATION_TABLE => "LinearizationTable",
        tag::BLACK_LEVEL_REPEAT_DIM => "BlackLevelRepeatDim",
        tag::BLACK_LEVEL => "BlackLevel",
        tag::BLACK_LEVEL_DELTA_H => "BlackLevelDeltaH",
        tag::BLACK_LEVEL_DELTA_V => "BlackLevelDeltaV",
        tag::WHITE_LEVEL => "WhiteLevel",
        tag::COLOR_MATRIX_1 => "ColorMatrix1",
        tag::COLOR_MATRIX_2 => "ColorMatrix2",
        tag::AS_SHOT_NEUTRAL => "AsShotNeutral",
        tag::ACTIVE_AREA => "ActiveArea",
        _ => "tag",
    }
}

/// The most directories looked at for the main image (IFD0 and its SubIFDs).
const MAX_IFDS: usize = 16;

impl Main {
    fn parse(data: &[u8]) -> Parsed<Main> {
        let big_endian = match data.get(..4) {
            Some(b"II\x2a\x00") => false,
            Some(b"MM\x00\x2a") => true,
            _ => return Err("not a DNG: no TIFF header".into()),
        };
        let t = Tiff { data, big_endian };
        let ifd0 = t.ifd(t.u32(4)? as usize)?;
        if !ifd0.contains_key(&tag::DNG_VERSION) {
            return Err("not a DNG: no DNGVersion tag in the first directory".into());
        }
        let uints = |ifd: &Ifd, k: u16| -> Parsed<Option<Vec<u64>>> {
            ifd.get(&k).map(|&e| t.uints(e, named(k))).transpose()
        };
        let one = |ifd: &Ifd, k: u16, default: Option<u64>| -> Parsed<u64> {
            match uints(ifd, k)? {
                Some(v) if v.len() == 1 => Ok(v[0]),
                Some(v) => Err(format!("{} = {v:?}: one value expected", named(k))),
                None => default.ok_or_else(|| format!("no {} tag", named(k))),
            }
        };
        // The main image: the first of IFD0 and its SubIFDs with NewSubFileType 0, each
        // SubIFD parsed only when those before it are not.
        let is_main = |d: &Ifd| one(d, tag::NEW_SUBFILE_TYPE, Some(0)).ok() == Some(0);
        let sub = if is_main(&ifd0) {
            None
        } else {
            let mut found = None;
            for off in uints(&ifd0, tag::SUB_IFDS)?
                .unwrap_or_default()
                .into_iter()
                .take(MAX_IFDS)
            {
                let d = t.ifd(off as usize)?;
                if is_main(&d) {
                    found = Some(d);
                    break;
                }
            }
            Some(
                found
                    .ok_or("no full-resolution image (NewSubFileType 0) in IFD0 or its SubIFDs")?,
            )
        };
        let ifd = sub.as_ref().unwrap_or(&ifd0);
        let refuse = |k: u16, v: u64, why: &str| Err(format!("{} = {v}{why}", named(k)));

        let compression = one(ifd, tag::COMPRESSION, Some(1))?;
        if compression != 1 {
            let what = match compression {
                7 => " (lossless JPEG)",
                8 => " (Deflate)",
                34892 => " (lossy JPEG)",
                52546 => " (JPEG XL)",
                _ => "",
            };
            return refuse(
                tag::COMPRESSION,
                compression,
                &format!(
                    "{what}: focusd reads uncompressed DNGs only (Compression = 1); convert the \
                 raw file with compression off"
                ),
            );
        }
        let photometric = one(ifd, tag::PHOTOMETRIC, None)?;
        if photometric != u64::from(CFA) {
            let what = if photometric == 34892 {
                " (LinearRaw, already demosaiced)"
            } else {
                ""
            };
            return refuse(
                tag::PHOTOMETRIC,
                photometric,
                &format!("{what}: focusd reads colour filter array (Bayer) DNGs only, 32803"),
            );
        }
        let spp = one(ifd, tag::SAMPLES_PER_PIXEL, Some(1))?;
        if spp != 1 {
            return refuse(
                tag::SAMPLES_PER_PIXEL,
                spp,
                ": a CFA image has 1 sample a pixel",
            );
        }
        let bits = one(ifd, tag::BITS_PER_SAMPLE, Some(1))?;
        if !(8..=16).contains(&bits) {
            return refuse(
                tag::BITS_PER_SAMPLE,
                bits,
                ": focusd reads 8 to 16 bits a sample",
            );
        }
        let format = one(ifd, tag::SAMPLE_FORMAT, Some(1))?;
        if format != 1 {
            return refuse(
                tag::SAMPLE_FORMAT,
                format,
                ": focusd reads unsigned integer samples (1)",
            );
        }
        let (width, height) = (
            one(ifd, tag::IMAGE_WIDTH, None)? as usize,
            one(ifd, tag::IMAGE_LENGTH, None)? as usize,
        );
        if width < 2 || height < 2 || (width as u64) * (height as u64) > MAX_PIXELS {
            return Err(format!(
                "{width}x{height}: a mosaic of at least 2x2 and at most {MAX_PIXELS} pixels is read"
            ));
        }
        let dim = uints(ifd, tag::CFA_REPEAT_PATTERN_DIM)?.unwrap_or_default();
        if dim != [2, 2] {
            return Err(format!(
                "CFARepeatPatternDim = {dim:?}: focusd reads 2x2 Bayer patterns only"
            ));
        }
        let pattern = uints(ifd, tag::CFA_PATTERN)?.unwrap_or_default();
        let order = bayer_order(&pattern.iter().map(|&c| c as u32).collect::<Vec<_>>())
            .ok_or_else(|| {
                format!(
                    "CFAPattern = {pattern:?}: not a Bayer pattern (0 red, 1 green, 2 blue, \
                     two greens on a diagonal)"
                )
            })?;
        if let Some(planes) = uints(ifd, tag::CFA_PLANE_COLOR)? {
            if planes != [0, 1, 2] {
                return Err(format!(
                    "CFAPlaneColor = {planes:?}: focusd reads red, green and blue filters only"
                ));
            }
        }
        let layout = one(ifd, tag::CFA_LAYOUT, Some(1))?;
        if layout != 1 {
            return refuse(
                tag::CFA_LAYOUT,
                layout,
                ": focusd reads rectangular CFA layouts only (1)",
            );
        }
        if ifd.contains_key(&tag::LINEARIZATION_TABLE) {
            return Err("LinearizationTable present: focusd reads linear samples only".into());
        }
        for k in [tag::BLACK_LEVEL_DELTA_H, tag::BLACK_LEVEL_DELTA_V] {
            if let Some(&e) = ifd.get(&k) {
                let v = t.reals(e, named(k))?;
                if v.iter().any(|&d| d != 0.0) {
                    return Err(format!(
                        "{} has non-zero values: focusd reads one black level per pattern cell",
                        named(k)
                    ));
                }
            }
        }
        if let Some(area) = uints(ifd, tag::ACTIVE_AREA)? {
            if area != [0, 0, height as u64, width as u64] {
                return Err(format!(
                    "ActiveArea = {area:?}: focusd reads DNGs whose active area is the whole \
                     {width}x{height} image"
                ));
            }
        }
        let black_dim = uints(ifd, tag::BLACK_LEVEL_REPEAT_DIM)?.unwrap_or(vec![1, 1]);
        let black_values = match ifd.get(&tag::BLACK_LEVEL) {
            Some(&e) => t.reals(e, "BlackLevel")?,
            None => vec![0.0],
        };
        let black = match (black_dim.as_slice(), black_values.as_slice()) {
            ([1, 1], &[b]) => [b; 4],
            ([2, 2], &[a, b, c, d]) => [a, b, c, d],
            _ => {
                return Err(format!(
                    "BlackLevelRepeatDim = {black_dim:?} with {} BlackLevel values: focusd \
                     reads 1x1 or 2x2",
                    black_values.len()
                ))
            }
        };
        let max_code = (1u64 << bits) - 1;
        let white = one(ifd, tag::WHITE_LEVEL, Some(max_code))?;
        if white > max_code || black.iter().any(|&b| !(b >= 0.0 && b < white as f64)) {
            return Err(format!(
                "BlackLevel = {black:?}, WhiteLevel = {white}: the levels must satisfy 0 <= \
                 black < white <= {max_code} at {bits} bits"
            ));
        }
        let orientation = match one(&ifd0, tag::ORIENTATION, Some(1))? {
            1 => Orientation::UPRIGHT,
            6 => Orientation::clockwise(1),
            3 => Orientation::clockwise(2),
            8 => Orientation::clockwise(3),
            o => {
                return refuse(
                    tag::ORIENTATION,
                    o,
                    ": focusd reads unmirrored orientations (1, 3, 6, 8)",
                )
            }
        };
        let matrix = Self::matrix(&t, &ifd0)?;
        let white_balance = Self::white_balance(&t, &ifd0)?;
        let chunks = if ifd.contains_key(&tag::TILE_OFFSETS) {
            Chunks::Tiles {
                width: one(ifd, tag::TILE_WIDTH, None)? as usize,
                length: one(ifd, tag::TILE_LENGTH, None)? as usize,
                offsets: uints(ifd, tag::TILE_OFFSETS)?.unwrap_or_default(),
            }
        } else {
            Chunks::Strips {
                rows: one(ifd, tag::ROWS_PER_STRIP, Some(height as u64))?.min(height as u64)
                    as usize,
                offsets: uints(ifd, tag::STRIP_OFFSETS)?
                    .ok_or("no StripOffsets or TileOffsets tag")?,
            }
        };
        Ok(Main {
            big_endian,
            width,
            height,
            bits: bits as u32,
            order,
            black,
            white,
            matrix,
            white_balance,
            orientation,
            chunks,
        })
    }

    /// The gains of AsShotNeutral (the camera's RGB of a neutral grey): its inverse, green's
    /// gain 1. `None` where the file has none (AsShotWhiteXY alone is not read).
    fn white_balance(t: &Tiff, ifd0: &Ifd) -> Parsed<Option<[f32; 3]>> {
        let Some(&e) = ifd0.get(&tag::AS_SHOT_NEUTRAL) else {
            return Ok(None);
        };
        match t.reals(e, named(tag::AS_SHOT_NEUTRAL))?[..] {
            [r, g, b] if [r, g, b].iter().all(|v| v.is_finite() && *v > 1e-6) => {
                Ok(Some([(g / r) as f32, 1.0, (g / b) as f32]))
            }
            ref v => Err(format!(
                "AsShotNeutral = {v:?}: focusd reads three positive values (red, green, blue)"
            )),
        }
    }

    /// The development matrix of the D65 colour matrix (ColorMatrix1 if none is for D65); the
    /// identity where there is none.
    fn matrix(t: &Tiff, ifd0: &Ifd) -> Parsed<[[f32; 3]; 3]> {
        let illuminant = |k| {
            ifd0.get(&k)
                .and_then(|&e| t.uints(e, "CalibrationIlluminant").ok())
                .and_then(|v| v.first().copied())
        };
        let key = if illuminant(tag::CALIBRATION_ILLUMINANT_2) == Some(u64::from(D65))
            && ifd0.contains_key(&tag::COLOR_MATRIX_2)
        {
            tag::COLOR_MATRIX_2
        } else {
            tag::COLOR_MATRIX_1
        };
        let Some(&e) = ifd0.get(&key) else {
            return Ok(IDENTITY);
        };
        let v = t.reals(e, named(key))?;
        if v.len() != 9 {
            return Err(format!(
                "{} has {} values: focusd reads three-colour (3x3) matrices",
                named(key),
                v.len()
            ));
        }
        development_matrix(Matrix3::from_row_slice(&v)).ok_or_else(|| {
            format!(
                "{} = {v:?} is singular or maps white out of range",
                named(key)
            )
        })
    }

    /// Bytes a row of `n` samples takes (rows start on a byte).
    fn row_bytes(&self, n: usize) -> usize {
        (n * self.bits as usize).div_ceil(8)
    }

    /// The samples row by row. The image's bytes must be in the file before anything is
    /// allocated for them, so the allocation is bounded by the file's size.
    fn samples(&self, data: &[u8]) -> Parsed<Vec<u16>> {
        self.held_in(data)?;
        let w = self.width;
        let mut out = vec![0u16; w * self.height];
        self.rows(data, |line, y, x0, n| {
            self.unpack(line, &mut out[y * w + x0..][..n])
        })?;
        Ok(out)
    }

    /// The file's bytes of the mosaic as they are, row after row, where each sample is a byte
    /// or a little-endian 16-bit word: no unpacking, and no buffer of samples between the file
    /// and the frame.
    fn bytes_as_they_are(&self, data: &[u8]) -> Parsed<Vec<u8>> {
        self.held_in(data)?;
        let bytes = (self.bits / 8) as usize;
        let row = self.width * bytes;
        let mut out = vec![0u8; row * self.height];
        self.rows(data, |line, y, x0, n| {
            out[y * row + x0 * bytes..][..n * bytes].copy_from_slice(&line[..n * bytes])
        })?;
        Ok(out)
    }

    /// An error unless `data` is long enough to hold the mosaic, checked before anything is
    /// allocated for it.
    fn held_in(&self, data: &[u8]) -> Parsed<()> {
        let (w, h) = (self.width, self.height);
        if self.row_bytes(w) * h > data.len() {
            return Err(format!(
                "truncated: a {w}x{h} mosaic of {} bits needs {} bytes, the file has {}",
                self.bits,
                self.row_bytes(w) * h,
                data.len()
            ));
        }
        Ok(())
    }

    /// Hands `put` each stored row of the mosaic: its bytes (at least enough for its samples),
    /// its row, its first column and how many samples of it are in the image.
    fn rows(&self, data: &[u8], mut put: impl FnMut(&[u8], usize, usize, usize)) -> Parsed<()> {
        let t = Tiff {
            data,
            big_endian: self.big_endian,
        };
        let (w, h) = (self.width, self.height);
        match &self.chunks {
            Chunks::Strips { rows, offsets } => {
                let rows = (*rows).max(1);
                if offsets.len() != h.div_ceil(rows) {
                    return Err(format!(
                        "StripOffsets has {} strips, {} expected for {h} rows of {rows}",
                        offsets.len(),
                        h.div_ceil(rows)
                    ));
                }
                for (i, &off) in offsets.iter().enumerate() {
                    let y0 = i * rows;
                    let n = rows.min(h - y0);
                    let rb = self.row_bytes(w);
                    let strip = t
                        .bytes(off as usize, rb * n)
                        .map_err(|e| format!("strip {i}: {e}"))?;
                    for (r, line) in strip.chunks_exact(rb).enumerate() {
                        put(line, y0 + r, 0, w);
                    }
                }
            }
            Chunks::Tiles {
                width: tw,
                length: tl,
                offsets,
            } => {
                let (tw, tl) = (*tw, *tl);
                if tw == 0 || tl == 0 || tw > w.max(16) * 16 || tl > h.max(16) * 16 {
                    return Err(format!("TileWidth = {tw}, TileLength = {tl}: out of range"));
                }
                let (across, down) = (w.div_ceil(tw), h.div_ceil(tl));
                if offsets.len() != across * down {
                    return Err(format!(
                        "TileOffsets has {} tiles, {} expected",
                        offsets.len(),
                        across * down
                    ));
                }
                let rb = self.row_bytes(tw);
                for (i, &off) in offsets.iter().enumerate() {
                    let (x0, y0) = (i % across * tw, i / across * tl);
                    let tile = t
                        .bytes(off as usize, rb * tl)
                        .map_err(|e| format!("tile {i}: {e}"))?;
                    let n = tw.min(w - x0);
                    for (r, line) in tile.chunks_exact(rb).take(tl.min(h - y0)).enumerate() {
                        put(line, y0 + r, x0, n);
                    }
                }
            }
        }
        Ok(())
    }

    /// One row's samples: bytes, 16-bit words in the file's byte order, or other depths packed
    /// from the most significant bit.
    fn unpack(&self, line: &[u8], out: &mut [u16]) {
        match self.bits {
            8 => out
                .iter_mut()
                .zip(line)
                .for_each(|(o, &b)| *o = u16::from(b)),
            16 => out.iter_mut().zip(line.chunks_exact(2)).for_each(|(o, p)| {
                *o = if self.big_endian {
                    u16::from_be_bytes([p[0], p[1]])
                } else {
                    u16::from_le_bytes([p[0], p[1]])
                }
            }),
            bits => {
                let mut bit = 0usize;
                for o in out.iter_mut() {
                    let mut v = 0u32;
                    for _ in 0..bits {
                        v = v << 1 | u32::from(line[bit / 8] >> (7 - bit % 8) & 1);
                        bit += 1;
                    }
                    *o = v as u16;
                }
            }
        }
    }

    /// The raw frame: kept as read where the levels fit one of the camera's packings (8 bits
    /// at white 255, 10 at 1023, 16 at 65535, one black level), else rescaled to 16 bits with
    /// every cell's black level at one code and the white level at 65535.
    fn raw_frame(&self, data: &[u8]) -> Parsed<RawFrame> {
        let uniform = self
            .black
            .iter()
            .all(|&b| b == self.black[0] && b.fract() == 0.0);
        let packing = match (self.bits, self.white) {
            (8, 255) if uniform => Some(Packing::Bits8),
            (_, 1023) if uniform => Some(Packing::Le10),
            (16, 65535) if uniform => Some(Packing::Le16),
            _ => None,
        };
        // A byte a sample, or a little-endian word a sample: the packing's own bytes.
        let as_they_are = match packing {
            Some(Packing::Bits8) => self.bits == 8,
            Some(Packing::Le10 | Packing::Le16) => self.bits == 16 && !self.big_endian,
            _ => false,
        };
        let (packing, black, bytes) = match packing {
            Some(p) if as_they_are => (p, self.black[0] as u32, self.bytes_as_they_are(data)?),
            Some(p) => {
                let samples = self.samples(data)?;
                (p, self.black[0] as u32, raw::pack(p, self.width, &samples))
            }
            None => {
                let samples = self.samples(data)?;
                let top = self.black.iter().copied().fold(0.0, f64::max);
                let to = (top * 65535.0 / self.white as f64).round();
                let white = self.white as f64;
                let rescaled: Vec<u16> = samples
                    .iter()
                    .enumerate()
                    .map(|(i, &s)| {
                        let (x, y) = (i % self.width, i / self.width);
                        let b = self.black[(y & 1) * 2 + (x & 1)];
                        let v = (f64::from(s) - b) / (white - b) * (65535.0 - to) + to;
                        v.round().clamp(0.0, 65535.0) as u16
                    })
                    .collect();
                let bytes = raw::pack(Packing::Le16, self.width, &rescaled);
                (Packing::Le16, to as u32, bytes)
            }
        };
        Ok(RawFrame {
            stride: packing.row_bytes(self.width),
            bytes,
            packing,
            width: self.width,
            height: self.height,
            order: self.order,
            black_level: black,
            matrix: self.matrix,
            white_balance: self.white_balance,
        })
    }
}
