//! Raw sensor samples out of a frame buffer: one byte a sample, MIPI CSI-2 RAW10 packing (four
//! samples in five bytes, what CSI receivers such as Qualcomm's store unaltered), or one
//! little-endian 16-bit word a sample holding 10 or 16 significant bits.

/// How a raw frame's samples sit in memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Packing {
    /// One byte a sample (V4L2's SRGGB8).
    Bits8,
    /// MIPI RAW10 (V4L2's SRGGB10P): per four samples, their high eight bits in four bytes, then
    /// one byte of their low two bits, the first sample's in bits 1..0.
    Mipi10,
    /// A little-endian 16-bit word a sample, 10 bits in its low bits (V4L2's SRGGB10).
    Le10,
    /// A little-endian 16-bit word a sample, all 16 bits significant (V4L2's SRGGB16).
    Le16,
}

impl Packing {
    /// Significant bits a sample.
    pub fn bits(self) -> u32 {
        match self {
            Packing::Bits8 => 8,
            Packing::Mipi10 | Packing::Le10 => 10,
            Packing::Le16 => 16,
        }
    }

    /// The bytes a row of `width` samples takes without padding.
    pub fn row_bytes(self, width: usize) -> usize {
        match self {
            Packing::Bits8 => width,
            Packing::Mipi10 => (width * 10).div_ceil(8),
            Packing::Le10 | Packing::Le16 => width * 2,
        }
    }
}

/// Checks that `len` bytes hold a `width`×`height` frame at `stride` bytes a row (0: rows
/// unpadded; the last row need not be padded); returns the stride and the bytes the frame
/// takes. A buffer too short for the geometry, or a stride shorter than a row, is an error
/// naming both.
pub fn layout(
    packing: Packing,
    width: usize,
    height: usize,
    stride: usize,
    len: usize,
) -> Result<(usize, usize), String> {
    let row = packing.row_bytes(width);
    let stride = if stride == 0 { row } else { stride };
    if stride < row {
        return Err(format!(
            "stride {stride} is shorter than a row of {width} samples ({row} bytes)"
        ));
    }
    let needed = stride * height.saturating_sub(1) + row;
    if height == 0 || width == 0 || len < needed {
        return Err(format!(
            "{width}x{height} frame: buffer of {len} bytes is too short, {needed} needed"
        ));
    }
    Ok((stride, needed))
}

/// The samples of a `width`×`height` frame, row by row, laid out as [`layout`] checks.
pub fn unpack(
    packing: Packing,
    width: usize,
    height: usize,
    stride: usize,
    bytes: &[u8],
) -> Result<Vec<u16>, String> {
    let (stride, _) = layout(packing, width, height, stride, bytes.len())?;
    let row = packing.row_bytes(width);
    let mut out = vec![0; width * height];
    for (y, samples) in out.chunks_exact_mut(width).enumerate() {
        read_row(packing, &bytes[y * stride..][..row], 0, samples);
    }
    Ok(out)
}

/// Samples `x0..x0 + out.len()` of a row whose bytes are `line` (exactly the row's, unpadded:
/// [`Packing::row_bytes`]), as [`unpack`] reads them, with no buffer for the whole row.
#[inline]
pub fn read_row(packing: Packing, line: &[u8], x0: usize, out: &mut [u16]) {
    match packing {
        Packing::Bits8 => {
            for (o, &b) in out.iter_mut().zip(&line[x0..]) {
                *o = u16::from(b);
            }
        }
        Packing::Le10 | Packing::Le16 => {
            for (o, p) in out.iter_mut().zip(line[2 * x0..].chunks_exact(2)) {
                *o = u16::from_le_bytes([p[0], p[1]]);
            }
        }
        Packing::Mipi10 => {
            // A row's last group may hold fewer than four samples, its low-bits byte last.
            let last = line.len() - 1;
            for (k, o) in out.iter_mut().enumerate() {
                let (group, i) = ((x0 + k) / 4 * 5, (x0 + k) % 4);
                let low = line[(group + 4).min(last)];
                *o = u16::from(line[group + i]) << 2 | u16::from(low >> (2 * i)) & 3;
            }
        }
    }
}

/// `samples` (row by row, `width` a row) in the packing's bytes, rows unpadded: what
/// [`unpack`] reads back. Samples above the packing's depth are cut to its low bits.
pub fn pack(packing: Packing, width: usize, samples: &[u16]) -> Vec<u8> {
    let mut out =
        Vec::with_capacity(samples.len().div_ceil(width.max(1)) * packing.row_bytes(width));
    for row in samples.chunks(width.max(1)) {
        match packing {
            Packing::Bits8 => out.extend(row.iter().map(|&s| s as u8)),
            Packing::Le10 | Packing::Le16 => out.extend(row.iter().flat_map(|s| s.to_le_bytes())),
            Packing::Mipi10 => {
                for group in row.chunks(4) {
                    out.extend(group.iter().map(|&s| (s >> 2) as u8));
                    out.push(
                        group
                            .iter()
                            .enumerate()
                            .fold(0, |low, (i, &s)| low | ((s & 3) as u8) << (2 * i)),
                    );
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const PACKINGS: [Packing; 4] = [
        Packing::Bits8,
        Packing::Mipi10,
        Packing::Le10,
        Packing::Le16,
    ];

    /// `n` samples spread over the packing's depth.
    fn spread(packing: Packing, n: u32) -> Vec<u16> {
        let max = (1u32 << packing.bits()) - 1;
        (0..n)
            .map(|i| ((i * 7919 + 13) % (max + 1)) as u16)
            .collect()
    }

    #[test]
    fn pack_is_what_unpack_reads() {
        // 6 samples a row leaves MIPI RAW10 a partial group at each row's end.
        for packing in PACKINGS {
            let samples = spread(packing, 18);
            let bytes = pack(packing, 6, &samples);
            assert_eq!(bytes.len(), 3 * packing.row_bytes(6), "{packing:?}");
            assert_eq!(unpack(packing, 6, 3, 0, &bytes), Ok(samples), "{packing:?}");
        }
    }

    #[test]
    fn a_rows_samples_from_any_column_are_the_unpacked_ones() {
        // 7 samples a row leaves MIPI RAW10 a partial group of three.
        for packing in PACKINGS {
            let samples = spread(packing, 14);
            let bytes = pack(packing, 7, &samples);
            let row = packing.row_bytes(7);
            for y in 0..2 {
                for x0 in 0..7 {
                    let mut got = vec![0; 7 - x0];
                    read_row(packing, &bytes[y * row..][..row], x0, &mut got);
                    assert_eq!(got, samples[y * 7 + x0..][..7 - x0], "{packing:?} {x0}");
                }
            }
        }
    }

    #[test]
    fn mipi10_by_hand() {
        // Samples 0x3ff, 0x001, 0x200, 0x155: high bytes ff 00 80 55, low bits 11 01 00 01
        // from the first sample up: 0b01_00_01_11 = 0x47.
        let row = [0xff, 0x00, 0x80, 0x55, 0x47];
        assert_eq!(
            unpack(Packing::Mipi10, 4, 1, 0, &row),
            Ok(vec![0x3ff, 0x001, 0x200, 0x155])
        );
        assert_eq!(pack(Packing::Mipi10, 4, &[0x3ff, 0x001, 0x200, 0x155]), row);
    }

    #[test]
    fn mipi10_rows_with_stride_and_a_partial_group() {
        // 6 samples a row: one whole group and two samples of the next (8 bytes), rows of 10.
        let samples: Vec<u16> = (0..18).map(|i| (i * 59 + 7) % 1024).collect();
        let mut bytes = Vec::new();
        for r in samples.chunks(6) {
            // The partial group's low-bits byte ends the row, as a driver writes it.
            let mut line = pack(Packing::Mipi10, 6, r);
            assert_eq!(line[7], (r[4] & 3) as u8 | ((r[5] & 3) as u8) << 2);
            assert_eq!(line.len(), Packing::Mipi10.row_bytes(6));
            line.resize(10, 0xee);
            bytes.extend(line);
        }
        bytes.truncate(10 * 2 + 8);
        assert_eq!(unpack(Packing::Mipi10, 6, 3, 10, &bytes), Ok(samples));
        let e = unpack(Packing::Mipi10, 6, 3, 10, &bytes[..27]).expect_err("short");
        assert_eq!(e, "6x3 frame: buffer of 27 bytes is too short, 28 needed");
        let e = unpack(Packing::Mipi10, 6, 3, 7, &bytes).expect_err("stride");
        assert!(
            e.starts_with("stride 7 is shorter than a row of 6 samples (8 bytes)"),
            "{e}"
        );
    }

    #[test]
    fn sixteen_bit_words_are_little_endian() {
        let bytes = [0xff, 0x03, 0x00, 0x02, 0xee, 0xee, 0x34, 0x12, 0x01, 0x00];
        assert_eq!(
            unpack(Packing::Le10, 2, 2, 6, &bytes),
            Ok(vec![0x3ff, 0x200, 0x1234, 0x0001])
        );
        assert_eq!(
            unpack(Packing::Le16, 1, 1, 0, &[0xcd, 0xab]),
            Ok(vec![0xabcd])
        );
        assert_eq!(
            unpack(Packing::Bits8, 3, 1, 0, &[0, 128, 255]),
            Ok(vec![0, 128, 255])
        );
        assert!(unpack(Packing::Le16, 2, 1, 0, &[0; 3]).is_err());
        assert!(unpack(Packing::Bits8, 0, 1, 0, &[]).is_err());
    }
}
