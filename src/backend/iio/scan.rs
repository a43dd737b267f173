//! IIO scan elements: the `scan_elements/*_type` strings, the layout of one buffer record and
//! its decoding. Pure functions over strings and bytes, so they can be fuzzed.

/// How one scan element is stored, as `scan_elements/<channel>_type` describes it:
/// `[be|le]:[s|u]bits/storagebits[Xrepeat]>>shift`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScanType {
    pub big_endian: bool,
    pub signed: bool,
    /// Significant bits, 1..=storage_bits.
    pub bits: u32,
    /// 8, 16, 32 or 64.
    pub storage_bits: u32,
    /// Consecutive values of this element (quaternions: 4); 1 when the string has no `X`.
    pub repeat: u32,
    /// Right shift that brings the value to bit 0.
    pub shift: u32,
}

const EXPECTED: &str = "expected like be:s16/16>>0";

/// Parses a `scan_elements/*_type` string (already trimmed), e.g. `be:s16/16>>0`,
/// `le:s64/64>>0`, `le:u12/16X4>>4`. The error says what is wrong with the string; the caller
/// prefixes the file.
pub fn parse_scan_type(s: &str) -> Result<ScanType, String> {
    let bad = || format!("bad scan type {s:?}: {EXPECTED}");
    let (endian, rest) = s.split_once(':').ok_or_else(bad)?;
    let big_endian = match endian {
        "be" => true,
        "le" => false,
        _ => {
            return Err(format!(
                "bad scan type {s:?}: endianness must be be or le; {EXPECTED}"
            ))
        }
    };
    let signed = match rest.as_bytes().first() {
        Some(b's') => true,
        Some(b'u') => false,
        _ => {
            return Err(format!(
                "bad scan type {s:?}: sign must be s or u; {EXPECTED}"
            ))
        }
    };
    let (bits, rest) = rest[1..].split_once('/').ok_or_else(bad)?;
    let (storage_repeat, shift) = rest.split_once(">>").ok_or_else(bad)?;
    let (storage, repeat) = match storage_repeat.split_once('X') {
        Some((storage, repeat)) => (storage, Some(repeat)),
        None => (storage_repeat, None),
    };
    let number = |field: &str| -> Result<u32, String> {
        if field.is_empty() || !field.bytes().all(|b| b.is_ascii_digit()) {
            return Err(bad());
        }
        field
            .parse()
            .map_err(|_| format!("bad scan type {s:?}: {field} is too large"))
    };
    let ty = ScanType {
        big_endian,
        signed,
        bits: number(bits)?,
        storage_bits: number(storage)?,
        repeat: repeat.map_or(Ok(1), number)?,
        shift: number(shift)?,
    };
    ty.check()
        .map_err(|e| format!("bad scan type {s:?}: {e}"))?;
    Ok(ty)
}

impl ScanType {
    /// The limits the kernel's own types obey; [`Layout::new`] and the decoder rely on them.
    fn check(&self) -> Result<(), String> {
        let (bits, storage, shift) = (self.bits, self.storage_bits, self.shift);
        if ![8, 16, 32, 64].contains(&storage) {
            return Err(format!(
                "storage of {storage} bits (the kernel stores 8, 16, 32 or 64)"
            ));
        }
        if bits == 0 || bits > storage {
            return Err(format!("{bits} bits do not fit in {storage} storage bits"));
        }
        if shift > storage - bits {
            return Err(format!(
                ">>{shift} shifts the {bits} bits out of their {storage} storage bits"
            ));
        }
        if !(1..=255).contains(&self.repeat) {
            return Err(format!("repeat {} is not 1..=255", self.repeat));
        }
        Ok(())
    }

    fn storage_bytes(&self) -> usize {
        self.storage_bits as usize / 8
    }

    /// One value from exactly `storage_bytes()` bytes: shifted, masked to `bits` and
    /// sign-extended. Unsigned 64-bit values above `i64::MAX` saturate.
    fn decode(&self, bytes: &[u8]) -> i64 {
        let fold = |u: u64, &b: &u8| (u << 8) | u64::from(b);
        let raw = if self.big_endian {
            bytes.iter().fold(0, fold)
        } else {
            bytes.iter().rev().fold(0, fold)
        };
        let u = raw.checked_shr(self.shift).unwrap_or(0);
        if self.bits >= 64 {
            return if self.signed {
                u as i64
            } else {
                i64::try_from(u).unwrap_or(i64::MAX)
            };
        }
        let mask = (1u64 << self.bits) - 1;
        let u = u & mask;
        if self.signed && (u >> (self.bits - 1)) & 1 == 1 {
            (u | !mask) as i64
        } else {
            u as i64
        }
    }
}

/// One enabled scan element and where it sits in a record.
#[derive(Clone, Debug, PartialEq)]
pub struct Element {
    /// The channel's file prefix, e.g. `in_accel_x`, `in_timestamp`.
    pub channel: String,
    pub index: u32,
    pub ty: ScanType,
    /// Byte offset in the record.
    pub offset: usize,
    /// Position of its first value in [`decode_record`]'s output.
    pub first_value: usize,
}

/// The layout of one buffer record: the enabled elements in scan-index order, each aligned to
/// its size, the record padded to the largest of them (the kernel's `iio_compute_scan_bytes`).
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    elements: Vec<Element>,
    bytes: usize,
    values: usize,
}

/// The kernel's `ALIGN(x, a)`. For the power-of-two sizes drivers use this is ordinary
/// alignment; it is reproduced literally so an odd `Xrepeat` lands where the kernel puts it.
fn kernel_align(x: usize, a: usize) -> usize {
    (x + a - 1) & !(a - 1)
}

impl Layout {
    /// Lays out the enabled channels `(channel, scan index, type)`, given in any order.
    pub fn new(mut channels: Vec<(String, u32, ScanType)>) -> Result<Layout, String> {
        if channels.is_empty() {
            return Err("no scan element is enabled".into());
        }
        channels.sort_by_key(|c| c.1);
        if let Some(w) = channels.windows(2).find(|w| w[0].1 == w[1].1) {
            return Err(format!(
                "{} and {} have the same scan index {}",
                w[0].0, w[1].0, w[0].1
            ));
        }
        let (mut bytes, mut largest, mut values) = (0, 1, 0);
        let mut elements = Vec::with_capacity(channels.len());
        for (channel, index, ty) in channels {
            ty.check().map_err(|e| format!("{channel}: {e}"))?;
            let length = ty.storage_bytes() * ty.repeat as usize;
            let offset = kernel_align(bytes, length);
            bytes = offset + length;
            largest = largest.max(length);
            elements.push(Element {
                channel,
                index,
                ty,
                offset,
                first_value: values,
            });
            values += ty.repeat as usize;
        }
        Ok(Layout {
            elements,
            bytes: kernel_align(bytes, largest),
            values,
        })
    }

    pub fn elements(&self) -> &[Element] {
        &self.elements
    }

    /// Bytes per record.
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Where `channel`'s first value is in [`decode_record`]'s output.
    pub fn value_of(&self, channel: &str) -> Option<usize> {
        self.elements
            .iter()
            .find(|e| e.channel == channel)
            .map(|e| e.first_value)
    }
}

/// Decodes one record into its values, element by element (`repeat` values each), as
/// integers before offset and scale.
pub fn decode_record(layout: &Layout, record: &[u8]) -> Result<Vec<i64>, String> {
    if record.len() != layout.bytes {
        return Err(format!(
            "a record of {} bytes, the layout has {}",
            record.len(),
            layout.bytes
        ));
    }
    let mut out = Vec::with_capacity(layout.values);
    for e in &layout.elements {
        let n = e.ty.storage_bytes();
        for r in 0..e.ty.repeat as usize {
            let start = e.offset + r * n;
            let bytes = record
                .get(start..start + n)
                .ok_or_else(|| format!("{} runs past the end of the record", e.channel))?;
            out.push(e.ty.decode(bytes));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn ty(s: &str) -> ScanType {
        parse_scan_type(s).unwrap()
    }

    #[test]
    fn parses_the_kernel_formats() {
        assert_eq!(
            ty("be:s16/16>>0"),
            ScanType {
                big_endian: true,
                signed: true,
                bits: 16,
                storage_bits: 16,
                repeat: 1,
                shift: 0
            }
        );
        let t = ty("le:s64/64>>0");
        assert!(!t.big_endian && t.signed && t.bits == 64 && t.storage_bits == 64);
        let t = ty("le:u12/16>>4");
        assert!(!t.signed && t.bits == 12 && t.shift == 4 && t.repeat == 1);
        let t = ty("be:s32/32X4>>0");
        assert_eq!((t.repeat, t.storage_bits), (4, 32));
    }

    #[test]
    fn refuses_bad_strings_saying_why() {
        assert_eq!(
            parse_scan_type("be:s16").unwrap_err(),
            "bad scan type \"be:s16\": expected like be:s16/16>>0"
        );
        for (s, why) in [
            ("", "expected like"),
            ("xe:s16/16>>0", "endianness"),
            ("be:x16/16>>0", "sign"),
            ("be:s/16>>0", "expected like"),
            ("be:s16/16>>", "expected like"),
            ("be:s16/16>>-1", "expected like"),
            ("be:s+16/16>>0", "expected like"),
            ("be:s17/16>>0", "17 bits do not fit in 16"),
            ("be:s0/16>>0", "0 bits"),
            ("be:s16/12>>0", "storage of 12 bits"),
            ("be:s12/16>>5", ">>5 shifts"),
            ("be:s16/16X0>>0", "repeat 0"),
            ("be:s16/16X>>0", "expected like"),
            ("be:s99999999999/16>>0", "too large"),
            ("be:é16/16>>0", "sign"),
        ] {
            let e = parse_scan_type(s).unwrap_err();
            assert!(e.contains(why), "{s}: {e}");
        }
    }

    /// The PinePhone's inv_mpu6050 scan: accel x,y,z, temp, gyro x,y,z, timestamp.
    fn mpu_layout() -> Layout {
        let s16 = ty("be:s16/16>>0");
        let mut ch: Vec<_> = [
            "in_accel_x",
            "in_accel_y",
            "in_accel_z",
            "in_temp",
            "in_anglvel_x",
            "in_anglvel_y",
            "in_anglvel_z",
        ]
        .iter()
        .enumerate()
        .map(|(i, c)| (c.to_string(), i as u32, s16))
        .collect();
        ch.push(("in_timestamp".into(), 7, ty("le:s64/64>>0")));
        ch.reverse();
        Layout::new(ch).unwrap()
    }

    #[test]
    fn lays_out_the_mpu_record_like_the_kernel() {
        let l = mpu_layout();
        let offsets: Vec<usize> = l.elements().iter().map(|e| e.offset).collect();
        assert_eq!(offsets, [0, 2, 4, 6, 8, 10, 12, 16]);
        assert_eq!(l.bytes(), 24);
        assert_eq!(l.value_of("in_anglvel_x"), Some(4));
        assert_eq!(l.value_of("in_timestamp"), Some(7));
        assert_eq!(l.value_of("in_magn_x"), None);
        // Without temp the gyro moves up, and the timestamp still aligns to 8.
        let s16 = ty("be:s16/16>>0");
        let l = Layout::new(vec![
            ("a".into(), 0, s16),
            ("b".into(), 1, s16),
            ("c".into(), 2, s16),
            ("t".into(), 3, ty("le:s64/64>>0")),
        ])
        .unwrap();
        assert_eq!((l.elements()[3].offset, l.bytes()), (8, 16));
        // The record pads to the largest element: one u8 then one s32 is 8 bytes.
        let l = Layout::new(vec![
            ("a".into(), 0, ty("le:u8/8>>0")),
            ("b".into(), 1, ty("le:s32/32>>0")),
            ("c".into(), 2, ty("le:u8/8>>0")),
        ])
        .unwrap();
        let offsets: Vec<usize> = l.elements().iter().map(|e| e.offset).collect();
        assert_eq!((offsets, l.bytes()), (vec![0, 4, 8], 12));
    }

    #[test]
    fn layout_refuses_duplicates_and_nothing() {
        let s16 = ty("be:s16/16>>0");
        let e = Layout::new(vec![("a".into(), 1, s16), ("b".into(), 1, s16)]).unwrap_err();
        assert!(e.contains("a and b have the same scan index 1"), "{e}");
        assert!(Layout::new(vec![]).is_err());
        let mut broken = s16;
        broken.storage_bits = 0;
        let e = Layout::new(vec![("a".into(), 0, broken)]).unwrap_err();
        assert!(e.starts_with("a: storage of 0 bits"), "{e}");
    }

    #[test]
    fn decodes_a_synthetic_mpu_record() {
        let l = mpu_layout();
        let mut r = vec![0xAAu8; 24];
        for (i, v) in [1i16, -2, 16384, 3000, -32768, 32767, 5].iter().enumerate() {
            r[2 * i..2 * i + 2].copy_from_slice(&v.to_be_bytes());
        }
        r[16..24].copy_from_slice(&1_234_567_890_123i64.to_le_bytes());
        // Bytes 14..16 are padding and must not matter.
        assert_eq!(
            decode_record(&l, &r).unwrap(),
            [1, -2, 16384, 3000, -32768, 32767, 5, 1_234_567_890_123]
        );
        let e = decode_record(&l, &r[..23]).unwrap_err();
        assert_eq!(e, "a record of 23 bytes, the layout has 24");
    }

    #[test]
    fn decodes_shifts_unsigned_little_endian_and_repeats() {
        let l = Layout::new(vec![
            ("u".into(), 0, ty("le:u12/16>>4")),
            ("s".into(), 1, ty("le:s12/16>>4")),
            ("q".into(), 2, ty("be:s16/16X3>>0")),
            ("w".into(), 3, ty("le:u64/64>>0")),
        ])
        .unwrap();
        // u, s at 0 and 2; q (6 bytes) at the kernel's ALIGN(4, 6) = 8; w at 16; 24 bytes.
        let offsets: Vec<usize> = l.elements().iter().map(|e| e.offset).collect();
        assert_eq!((offsets, l.bytes()), (vec![0, 2, 8, 16], 24));
        let mut r = vec![0u8; 24];
        r[0..2].copy_from_slice(&((0xFFFu16 << 4) | 0xF).to_le_bytes());
        r[2..4].copy_from_slice(&((0x800u16 << 4) | 0x3).to_le_bytes());
        r[8..14].copy_from_slice(&[0x00, 0x01, 0xFF, 0xFE, 0x7F, 0xFF]);
        r[16..24].copy_from_slice(&u64::MAX.to_le_bytes());
        assert_eq!(
            decode_record(&l, &r).unwrap(),
            [4095, -2048, 1, -2, 32767, i64::MAX]
        );
        assert_eq!(l.value_of("w"), Some(5));
    }

    proptest! {
        #[test]
        fn parser_never_panics(s in ".{0,40}") {
            let _ = parse_scan_type(&s);
        }

        #[test]
        fn parser_never_panics_on_near_misses(
            s in "(be|le|xx)?:?[su]?[0-9]{0,3}/?[0-9]{0,3}(X[0-9]{0,4})?(>>)?[0-9]{0,3}"
        ) {
            if let Ok(t) = parse_scan_type(&s) {
                prop_assert!(t.check().is_ok());
            }
        }

        #[test]
        fn decoder_never_panics(
            types in proptest::collection::vec(
                "(be|le):[su][0-9]{1,2}/(8|16|32|64)(X[0-9])?>>[0-9]{1,2}", 1..8),
            indices in proptest::collection::vec(0u32..12, 8),
            bytes in proptest::collection::vec(any::<u8>(), 0..200),
        ) {
            let channels: Vec<_> = types
                .iter()
                .zip(&indices)
                .filter_map(|(s, &i)| parse_scan_type(s).ok().map(|t| (s.clone(), i, t)))
                .collect();
            if let Ok(layout) = Layout::new(channels) {
                let _ = decode_record(&layout, &bytes);
                let full: Vec<u8> = bytes.iter().copied().cycle().take(layout.bytes()).collect();
                if full.len() == layout.bytes() {
                    let values = decode_record(&layout, &full).unwrap();
                    prop_assert_eq!(values.len(), layout.values);
                }
            }
        }
    }
}
