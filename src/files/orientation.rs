//! Pictures upright as the phone was held: the quarter turns a picture needs (from the sensor's
//! mounting and the hold), written as the EXIF Orientation tag into a JPEG, or applied to the
//! pixels of formats without one in common use (PNG, TIFF).

use crate::stack::image::{Image, Sample};

/// Clockwise quarter turns that make a picture upright (0..=3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Orientation(u8);

impl Orientation {
    pub const UPRIGHT: Orientation = Orientation(0);

    pub fn clockwise(quarter_turns: u8) -> Orientation {
        Orientation(quarter_turns % 4)
    }

    /// From `V4L2_CID_CAMERA_SENSOR_ROTATION` (the device tree's `rotation`): the
    /// counter-clockwise correction in degrees, a multiple of 90.
    pub fn from_sensor_rotation(degrees: i64) -> Result<Orientation, String> {
        if degrees.rem_euclid(90) != 0 {
            return Err(format!(
                "sensor rotation {degrees}: not a multiple of 90 degrees"
            ));
        }
        Ok(Orientation::clockwise(
            (4 - (degrees.rem_euclid(360) / 90) as u8) % 4,
        ))
    }

    /// Both turns, one after the other.
    pub fn then(self, other: Orientation) -> Orientation {
        Orientation::clockwise(self.0 + other.0)
    }

    pub fn quarter_turns(self) -> u8 {
        self.0
    }

    /// The EXIF Orientation value: 1 upright, 6 turn 90° clockwise to view, 3 turn 180°,
    /// 8 turn 90° counter-clockwise.
    pub fn exif(self) -> u16 {
        [1, 6, 3, 8][usize::from(self.0)]
    }

    /// The pixels turned upright.
    pub fn turn<T: Sample>(self, img: &Image<T>) -> Image<T> {
        let (w, h, c) = (img.width(), img.height(), img.channels());
        let (ow, oh) = if self.0 % 2 == 1 { (h, w) } else { (w, h) };
        let mut out = vec![T::default(); w * h * c];
        let src = img.data();
        for y in 0..h {
            for x in 0..w {
                // Where (x, y) lands after the clockwise turns.
                let (nx, ny) = match self.0 {
                    0 => (x, y),
                    1 => (h - 1 - y, x),
                    2 => (w - 1 - x, h - 1 - y),
                    _ => (y, w - 1 - x),
                };
                let from = (y * w + x) * c;
                let to = (ny * ow + nx) * c;
                out[to..to + c].copy_from_slice(&src[from..from + c]);
            }
        }
        Image::from_vec(ow, oh, c, out)
    }
}

/// A JPEG with an APP1 Exif segment holding only the Orientation tag, placed right after the
/// start-of-image marker. The error names what is not a JPEG.
pub fn tag_jpeg(jpeg: &[u8], o: Orientation) -> Result<Vec<u8>, String> {
    if jpeg.len() < 2 || jpeg[..2] != [0xff, 0xd8] {
        return Err("not a JPEG: no start-of-image marker".into());
    }
    // A big-endian TIFF header, IFD0 at offset 8 with one entry: 0x0112 Orientation, SHORT,
    // count 1, the value left-aligned in the 4-byte field; no next IFD.
    let mut tiff = vec![
        b'M', b'M', 0, 42, 0, 0, 0, 8, 0, 1, 0x01, 0x12, 0, 3, 0, 0, 0, 1,
    ];
    tiff.extend(o.exif().to_be_bytes());
    tiff.extend([0, 0, 0, 0, 0, 0]);
    let mut body = b"Exif\0\0".to_vec();
    body.extend(tiff);
    let len = u16::try_from(body.len() + 2).map_err(|_| "EXIF segment too long".to_string())?;
    let mut out = Vec::with_capacity(jpeg.len() + body.len() + 4);
    out.extend([0xff, 0xd8, 0xff, 0xe1]);
    out.extend(len.to_be_bytes());
    out.extend(body);
    out.extend(&jpeg[2..]);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sensor_rotation_is_a_counter_clockwise_correction() {
        let exif = |deg| Orientation::from_sensor_rotation(deg).map(Orientation::exif);
        assert_eq!(exif(0), Ok(1));
        assert_eq!(exif(90), Ok(8));
        assert_eq!(exif(180), Ok(3));
        assert_eq!(exif(270), Ok(6));
        assert!(exif(45).expect_err("45").contains("not a multiple of 90"));
        let r270 = Orientation::from_sensor_rotation(270).expect("270");
        assert_eq!(r270.then(Orientation::clockwise(3)).exif(), 1);
    }

    #[test]
    fn turning_moves_the_corners_clockwise() {
        // 3x2, one channel: 0 1 2 / 3 4 5.
        let img = Image::from_vec(3, 2, 1, (0u8..6).collect());
        let quarter = Orientation::clockwise(1).turn(&img);
        assert_eq!((quarter.width(), quarter.height()), (2, 3));
        assert_eq!(quarter.data(), &[3, 0, 4, 1, 5, 2]);
        assert_eq!(
            Orientation::clockwise(2).turn(&img).data(),
            &[5, 4, 3, 2, 1, 0]
        );
        assert_eq!(
            Orientation::clockwise(3).turn(&img).data(),
            &[2, 5, 1, 4, 0, 3]
        );
        let back = Orientation::clockwise(3).turn(&quarter);
        assert_eq!(back.data(), img.data());
    }

    #[test]
    fn the_tag_reads_back_with_an_exif_reader() {
        let img = Image::from_vec(8, 8, 3, vec![128u8; 192]);
        let jpeg = crate::files::imageio::encode(&img, image::ImageFormat::Jpeg, 90).expect("jpeg");
        for turns in 0..4 {
            let o = Orientation::clockwise(turns);
            let tagged = tag_jpeg(&jpeg, o).expect("tagged");
            let exif = exif::Reader::new()
                .read_from_container(&mut std::io::Cursor::new(&tagged))
                .expect("exif");
            let f = exif
                .get_field(exif::Tag::Orientation, exif::In::PRIMARY)
                .expect("orientation");
            assert_eq!(f.value.get_uint(0), Some(u32::from(o.exif())));
            // Still a JPEG the decoder reads, pixels unchanged.
            let back = image::load_from_memory(&tagged).expect("decodes").to_rgb8();
            assert_eq!(back.dimensions(), (8, 8));
        }
        assert!(tag_jpeg(b"\x89PNG", Orientation::UPRIGHT).is_err());
    }
}
