//! Pixel formats: which to ask the driver for, and turning a buffer of one into RGB.

use crate::stack::image::Image;

/// The colour of the top-left 2×2 cell of a Bayer mosaic, by its V4L2 name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BayerOrder {
    Bggr,
    Gbrg,
    Grbg,
    Rggb,
}

impl BayerOrder {
    /// The channel (0 red, 1 green, 2 blue) of the sample at (x, y).
    fn channel(self, x: usize, y: usize) -> usize {
        let cell = match self {
            BayerOrder::Bggr => [[2, 1], [1, 0]],
            BayerOrder::Gbrg => [[1, 2], [0, 1]],
            BayerOrder::Grbg => [[1, 0], [2, 1]],
            BayerOrder::Rggb => [[0, 1], [1, 2]],
        };
        cell[y & 1][x & 1]
    }
}

/// The formats focusd converts; all 8 bits per sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    Yuyv,
    Uyvy,
    Nv12,
    /// NV12 with luma and chroma in two memory planes (`NM12`, multi-planar API only).
    Nv12m,
    Mjpg,
    Rgb3,
    Bayer(BayerOrder),
}

const ALL: [PixelFormat; 10] = [
    PixelFormat::Rgb3,
    PixelFormat::Yuyv,
    PixelFormat::Uyvy,
    PixelFormat::Nv12,
    PixelFormat::Nv12m,
    PixelFormat::Mjpg,
    PixelFormat::Bayer(BayerOrder::Bggr),
    PixelFormat::Bayer(BayerOrder::Gbrg),
    PixelFormat::Bayer(BayerOrder::Grbg),
    PixelFormat::Bayer(BayerOrder::Rggb),
];

impl PixelFormat {
    pub fn from_fourcc(code: &[u8; 4]) -> Option<PixelFormat> {
        ALL.into_iter().find(|f| &f.fourcc() == code)
    }

    pub fn fourcc(self) -> [u8; 4] {
        *match self {
            PixelFormat::Yuyv => b"YUYV",
            PixelFormat::Uyvy => b"UYVY",
            PixelFormat::Nv12 => b"NV12",
            PixelFormat::Nv12m => b"NM12",
            PixelFormat::Mjpg => b"MJPG",
            PixelFormat::Rgb3 => b"RGB3",
            PixelFormat::Bayer(BayerOrder::Bggr) => b"BA81",
            PixelFormat::Bayer(BayerOrder::Gbrg) => b"GBRG",
            PixelFormat::Bayer(BayerOrder::Grbg) => b"GRBG",
            PixelFormat::Bayer(BayerOrder::Rggb) => b"RGGB",
        }
    }

    /// A fourcc as the config writes it, case-insensitively.
    pub fn parse(s: &str) -> Result<PixelFormat, String> {
        let code: Option<[u8; 4]> = s.to_ascii_uppercase().as_bytes().try_into().ok();
        code.and_then(|c| PixelFormat::from_fourcc(&c))
            .ok_or_else(|| format!("not a format focusd converts; it converts {}", supported()))
    }

    /// Lower is better. Focus measures and registration want every pixel's own detail:
    /// RGB3 needs no conversion; YUYV/UYVY keep full-resolution luma losslessly (chroma is
    /// halved only horizontally); NV12 halves chroma both ways; MJPG adds block artefacts that
    /// look like texture to a focus measure; raw Bayer gets only a bilinear demosaic here, with
    /// no white balance or colour correction from the ISP.
    pub fn rank(self) -> u8 {
        match self {
            PixelFormat::Rgb3 => 0,
            PixelFormat::Yuyv | PixelFormat::Uyvy => 1,
            PixelFormat::Nv12 | PixelFormat::Nv12m => 2,
            PixelFormat::Mjpg => 3,
            PixelFormat::Bayer(_) => 4,
        }
    }
}

/// A fourcc for a message: its characters, or its hex value when they are not printable.
pub fn fourcc_str(code: &[u8; 4]) -> String {
    if code.iter().all(|b| b.is_ascii_graphic() || *b == b' ') {
        String::from_utf8_lossy(code).trim_end().to_string()
    } else {
        format!("0x{:08x}", u32::from_le_bytes(*code))
    }
}

fn supported() -> String {
    let names: Vec<String> = ALL.iter().map(|f| fourcc_str(&f.fourcc())).collect();
    names.join(", ")
}

fn offered_str(offered: &[[u8; 4]]) -> String {
    if offered.is_empty() {
        return "none".to_string();
    }
    let names: Vec<String> = offered.iter().map(fourcc_str).collect();
    names.join(", ")
}

/// The format to ask for: `wanted` if the device offers it, else the best it offers.
pub fn choose(offered: &[[u8; 4]], wanted: Option<&str>) -> Result<PixelFormat, String> {
    if let Some(w) = wanted {
        let f = PixelFormat::parse(w).map_err(|e| format!("format {w:?} is {e}"))?;
        if !offered.contains(&f.fourcc()) {
            return Err(format!(
                "it does not offer format {}; it offers {} (set [camera] format to one of them, \
                 or leave it out)",
                fourcc_str(&f.fourcc()),
                offered_str(offered)
            ));
        }
        return Ok(f);
    }
    offered
        .iter()
        .filter_map(PixelFormat::from_fourcc)
        .min_by_key(|f| f.rank())
        .ok_or_else(|| {
            format!(
                "it offers no format focusd converts: it offers {}, focusd converts {}",
                offered_str(offered),
                supported()
            )
        })
}

/// Checks that `bytes` holds `rows` lines of `line` bytes at `stride`, and returns the stride
/// to use (0 from a driver means tightly packed).
fn check_layout(
    what: &str,
    line: usize,
    stride: usize,
    rows: usize,
    offset: usize,
    bytes: &[u8],
) -> Result<usize, String> {
    let stride = if stride == 0 { line } else { stride };
    if stride < line {
        return Err(format!(
            "{what}: stride {stride} is shorter than a line of {line} bytes"
        ));
    }
    let need = offset + stride * (rows - 1) + line;
    if bytes.len() < need {
        return Err(format!(
            "{what}: buffer of {} bytes is too short, {need} needed",
            bytes.len()
        ));
    }
    Ok(stride)
}

/// BT.601 limited range (what YUV camera formats carry) to RGB, in 8.8 fixed point.
#[inline]
fn yuv_to_rgb(y: u8, u: u8, v: u8) -> [u8; 3] {
    let c = 298 * (i32::from(y) - 16);
    let d = i32::from(u) - 128;
    let e = i32::from(v) - 128;
    let clip = |x: i32| ((x + 128) >> 8).clamp(0, 255) as u8;
    [
        clip(c + 409 * e),
        clip(c - 100 * d - 208 * e),
        clip(c + 516 * d),
    ]
}

/// One frame in memory planes (the multi-planar API's buffers, each with its own bytes per
/// line) as 8-bit RGB: NM12's luma and chroma planes, or any format's single plane.
pub fn to_rgb_planes(
    fmt: PixelFormat,
    width: usize,
    height: usize,
    planes: &[(&[u8], usize)],
) -> Result<Image<u8>, String> {
    match (fmt, planes) {
        (PixelFormat::Nv12m, &[(luma, luma_stride), (chroma, chroma_stride)]) => {
            let name = fourcc_str(&fmt.fourcc());
            let (luma_stride, chroma_stride) = nv12_layout(
                &name,
                width,
                height,
                (luma, luma_stride),
                (chroma, chroma_stride),
            )?;
            let mut out = Vec::with_capacity(width * height * 3);
            nv12(
                width,
                height,
                (luma, luma_stride),
                (chroma, chroma_stride),
                &mut out,
            );
            Ok(Image::from_vec(width, height, 3, out))
        }
        (PixelFormat::Nv12m, _) => Err(format!(
            "NM12: {} memory planes, 2 expected (luma and chroma)",
            planes.len()
        )),
        (_, &[(bytes, stride)]) => to_rgb(fmt, width, height, stride, bytes),
        _ => Err(format!(
            "{}: {} memory planes, 1 expected",
            fourcc_str(&fmt.fourcc()),
            planes.len()
        )),
    }
}

/// Checks NV12's luma and chroma planes (`width` bytes by `height` and `height / 2` lines) and
/// returns their strides.
fn nv12_layout(
    name: &str,
    width: usize,
    height: usize,
    (luma, luma_stride): (&[u8], usize),
    (chroma, chroma_stride): (&[u8], usize),
) -> Result<(usize, usize), String> {
    if width % 2 != 0 || height % 2 != 0 {
        return Err(format!("{name}: odd frame size {width}x{height}"));
    }
    Ok((
        check_layout(name, width, luma_stride, height, 0, luma)?,
        check_layout(name, width, chroma_stride, height / 2, 0, chroma)?,
    ))
}

/// NV12 to RGB: full-resolution luma, one U,V pair per 2×2 pixels.
fn nv12(
    width: usize,
    height: usize,
    (luma, luma_stride): (&[u8], usize),
    (chroma, chroma_stride): (&[u8], usize),
    out: &mut Vec<u8>,
) {
    for y in 0..height {
        let l = &luma[y * luma_stride..][..width];
        let c = &chroma[(y / 2) * chroma_stride..][..width];
        for (x, &v) in l.iter().enumerate() {
            let x = x & !1;
            out.extend_from_slice(&yuv_to_rgb(v, c[x], c[x + 1]));
        }
    }
}

/// One frame of `fmt` in one buffer as 8-bit RGB. `stride` is the driver's bytes per line (0:
/// packed); for NV12 (and NM12's planes laid end to end) it applies to both planes. A buffer
/// too short for the geometry is an error.
pub fn to_rgb(
    fmt: PixelFormat,
    width: usize,
    height: usize,
    stride: usize,
    bytes: &[u8],
) -> Result<Image<u8>, String> {
    let name = fourcc_str(&fmt.fourcc());
    if width == 0 || height == 0 {
        return Err(format!("{name}: empty frame size {width}x{height}"));
    }
    let mut out = Vec::with_capacity(width * height * 3);
    match fmt {
        PixelFormat::Rgb3 => {
            let stride = check_layout(&name, width * 3, stride, height, 0, bytes)?;
            for row in bytes.chunks(stride).take(height) {
                out.extend_from_slice(&row[..width * 3]);
            }
        }
        PixelFormat::Yuyv | PixelFormat::Uyvy => {
            if width % 2 != 0 {
                return Err(format!("{name}: odd width {width}"));
            }
            let stride = check_layout(&name, width * 2, stride, height, 0, bytes)?;
            // Byte offsets of Y0, U, Y1, V in each 4-byte pair of pixels.
            let [y0, u, y1, v] = if fmt == PixelFormat::Yuyv {
                [0, 1, 2, 3]
            } else {
                [1, 0, 3, 2]
            };
            for row in bytes.chunks(stride).take(height) {
                for p in row[..width * 2].chunks_exact(4) {
                    out.extend_from_slice(&yuv_to_rgb(p[y0], p[u], p[v]));
                    out.extend_from_slice(&yuv_to_rgb(p[y1], p[u], p[v]));
                }
            }
        }
        PixelFormat::Nv12 | PixelFormat::Nv12m => {
            let stride = if stride == 0 { width } else { stride };
            let (luma, chroma) = bytes.split_at(bytes.len().min(stride * height));
            nv12_layout(&name, width, height, (luma, stride), (chroma, stride))?;
            nv12(width, height, (luma, stride), (chroma, stride), &mut out);
        }
        PixelFormat::Mjpg => {
            let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg)
                .map_err(|e| format!("{name}: cannot decode the frame: {e}"))?;
            if (img.width() as usize, img.height() as usize) != (width, height) {
                return Err(format!(
                    "{name}: the frame decodes to {}x{}, not the negotiated {width}x{height}",
                    img.width(),
                    img.height()
                ));
            }
            out = img.into_rgb8().into_raw();
        }
        PixelFormat::Bayer(order) => {
            if width < 2 || height < 2 {
                return Err(format!(
                    "{name}: frame {width}x{height} is smaller than 2x2"
                ));
            }
            let stride = check_layout(&name, width, stride, height, 0, bytes)?;
            demosaic(order, width, height, stride, bytes, &mut out);
        }
    }
    Ok(Image::from_vec(width, height, 3, out))
}

/// Bilinear demosaic: each missing channel is the mean of that channel's samples in the 3×3
/// neighbourhood (inside the frame), which is the bilinear interpolation of the Bayer grid.
/// Any 3×3 window clipped to a frame of at least 2×2 holds a whole 2×2 cell, so every channel
/// has a sample.
fn demosaic(
    order: BayerOrder,
    width: usize,
    height: usize,
    stride: usize,
    bytes: &[u8],
    out: &mut Vec<u8>,
) {
    for y in 0..height {
        for x in 0..width {
            let own = order.channel(x, y);
            let mut sum = [0u32; 3];
            let mut count = [0u32; 3];
            for ny in y.saturating_sub(1)..=(y + 1).min(height - 1) {
                for nx in x.saturating_sub(1)..=(x + 1).min(width - 1) {
                    let c = order.channel(nx, ny);
                    sum[c] += u32::from(bytes[ny * stride + nx]);
                    count[c] += 1;
                }
            }
            for c in 0..3 {
                out.push(if c == own {
                    bytes[y * stride + x]
                } else {
                    ((sum[c] + count[c] / 2) / count[c]) as u8
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_flat(img: &Image<u8>, rgb: [u8; 3], tol: u8) {
        for (i, px) in img.data.chunks_exact(3).enumerate() {
            for c in 0..3 {
                assert!(
                    px[c].abs_diff(rgb[c]) <= tol,
                    "pixel {i}: {px:?}, expected {rgb:?}"
                );
            }
        }
    }

    #[test]
    fn fourccs_round_trip() {
        for f in ALL {
            assert_eq!(PixelFormat::from_fourcc(&f.fourcc()), Some(f));
        }
        assert_eq!(PixelFormat::from_fourcc(b"H264"), None);
        assert_eq!(
            PixelFormat::from_fourcc(b"BA81"),
            Some(PixelFormat::Bayer(BayerOrder::Bggr))
        );
        assert_eq!(PixelFormat::parse("nv12"), Ok(PixelFormat::Nv12));
        assert!(PixelFormat::parse("NV1").is_err());
        assert_eq!(fourcc_str(b"Y16 "), "Y16");
        assert_eq!(fourcc_str(&[0, 1, 2, 3]), "0x03020100");
    }

    #[test]
    fn choose_prefers_by_rank() {
        let offered = [*b"BA81", *b"MJPG", *b"NV12", *b"YUYV", *b"H264"];
        assert_eq!(choose(&offered, None), Ok(PixelFormat::Yuyv));
        assert_eq!(choose(&offered[..3], None), Ok(PixelFormat::Nv12));
        assert_eq!(choose(&offered[..2], None), Ok(PixelFormat::Mjpg));
        assert_eq!(
            choose(&offered[..1], None),
            Ok(PixelFormat::Bayer(BayerOrder::Bggr))
        );
        assert_eq!(choose(&[*b"UYVY", *b"RGB3"], None), Ok(PixelFormat::Rgb3));
        assert_eq!(
            choose(&offered, Some("ba81")),
            Ok(PixelFormat::Bayer(BayerOrder::Bggr))
        );
    }

    #[test]
    fn choose_errors_list_what_is_offered() {
        let e = choose(&[*b"H264", *b"Y10 "], None).expect_err("nothing usable");
        assert!(
            e.contains("it offers H264, Y10") && e.contains("YUYV"),
            "{e}"
        );
        let e = choose(&[*b"YUYV", *b"MJPG"], Some("NV12")).expect_err("not offered");
        assert!(
            e.contains("does not offer format NV12; it offers YUYV, MJPG"),
            "{e}"
        );
        let e = choose(&[*b"YUYV"], Some("H264")).expect_err("unsupported");
        assert!(e.contains("not a format focusd converts"), "{e}");
        let e = choose(&[], None).expect_err("no formats");
        assert!(e.contains("it offers none"), "{e}");
    }

    fn yuyv(w: usize, h: usize, [y, u, v]: [u8; 3], stride: usize) -> Vec<u8> {
        let mut b = vec![0xee; stride * h];
        for row in 0..h {
            for pair in 0..w / 2 {
                b[row * stride + pair * 4..][..4].copy_from_slice(&[y, u, y, v]);
            }
        }
        b
    }

    #[test]
    fn yuyv_grey_and_red() {
        let grey =
            to_rgb(PixelFormat::Yuyv, 4, 2, 8, &yuyv(4, 2, [126, 128, 128], 8)).expect("converts");
        assert_eq!((grey.width, grey.height, grey.channels), (4, 2, 3));
        assert_flat(&grey, [128, 128, 128], 0);
        // Pure red in BT.601 limited range.
        let red =
            to_rgb(PixelFormat::Yuyv, 4, 2, 8, &yuyv(4, 2, [81, 90, 240], 8)).expect("converts");
        assert_flat(&red, [255, 0, 0], 1);
        let black = to_rgb(PixelFormat::Yuyv, 2, 1, 0, &[16, 128, 16, 128]).expect("converts");
        assert_flat(&black, [0, 0, 0], 0);
    }

    #[test]
    fn yuyv_stride_padding_is_ignored_and_short_buffers_refused() {
        // 0xee padding after each 8-byte line would turn a pixel pink if it were read.
        let img = to_rgb(
            PixelFormat::Yuyv,
            4,
            3,
            12,
            &yuyv(4, 3, [235, 128, 128], 12),
        )
        .expect("converts");
        assert_flat(&img, [255, 255, 255], 0);
        let mut b = yuyv(4, 3, [235, 128, 128], 12);
        b.truncate(12 * 2 + 7);
        let e = to_rgb(PixelFormat::Yuyv, 4, 3, 12, &b).expect_err("short");
        assert!(e.contains("too short, 32 needed"), "{e}");
        let e = to_rgb(PixelFormat::Yuyv, 4, 3, 6, &b).expect_err("narrow stride");
        assert!(e.contains("stride 6 is shorter"), "{e}");
        assert!(
            to_rgb(PixelFormat::Yuyv, 3, 1, 0, &[0; 8]).is_err(),
            "odd width"
        );
        assert!(to_rgb(PixelFormat::Yuyv, 0, 1, 0, &[]).is_err(), "empty");
    }

    #[test]
    fn uyvy_red() {
        let b = [90u8, 81, 240, 81].repeat(4);
        let img = to_rgb(PixelFormat::Uyvy, 4, 2, 0, &b).expect("converts");
        assert_flat(&img, [255, 0, 0], 1);
    }

    #[test]
    fn nv12_red_with_stride_and_short_buffer() {
        let (w, h, stride) = (4, 4, 6);
        let mut b = vec![0xee; stride * h + stride * h / 2];
        for y in 0..h {
            b[y * stride..][..w].fill(81);
        }
        for y in 0..h / 2 {
            for x in (0..w).step_by(2) {
                b[stride * h + y * stride + x] = 90;
                b[stride * h + y * stride + x + 1] = 240;
            }
        }
        let img = to_rgb(PixelFormat::Nv12, w, h, stride, &b).expect("converts");
        assert_flat(&img, [255, 0, 0], 1);
        let e = to_rgb(PixelFormat::Nv12, w, h, stride, &b[..stride * h + 3])
            .expect_err("no chroma plane");
        assert!(e.contains("too short"), "{e}");
        // The same frame in two memory planes (NM12), each with its own stride.
        let (luma, chroma) = b.split_at(stride * h);
        let packed: Vec<u8> = chroma
            .chunks(stride)
            .flat_map(|r| &r[..w])
            .copied()
            .collect();
        let planes = [(luma, stride), (&packed[..], w)];
        let img2 = to_rgb_planes(PixelFormat::Nv12m, w, h, &planes).expect("converts");
        assert_eq!(img2.data, img.data);
        let e = to_rgb_planes(PixelFormat::Nv12m, w, h, &planes[..1]).expect_err("one plane");
        assert!(e.contains("1 memory planes, 2 expected"), "{e}");
        let e = to_rgb_planes(PixelFormat::Nv12m, w, h, &[planes[0], (&packed[..5], w)])
            .expect_err("short chroma");
        assert!(e.contains("too short"), "{e}");
        // A one-plane format through the planes API is the single-buffer conversion.
        let yuyv = [126u8, 128, 126, 128];
        assert_eq!(
            to_rgb_planes(PixelFormat::Yuyv, 2, 1, &[(&yuyv[..], 4)]),
            to_rgb(PixelFormat::Yuyv, 2, 1, 4, &yuyv)
        );
        assert!(to_rgb_planes(PixelFormat::Yuyv, 2, 1, &planes).is_err());
    }

    #[test]
    fn rgb3_honours_stride() {
        let mut b = vec![0xee; 2 * 8];
        for row in 0..2 {
            b[row * 8..][..6].copy_from_slice(&[10, 20, 30, 10, 20, 30]);
        }
        let img = to_rgb(PixelFormat::Rgb3, 2, 2, 8, &b).expect("converts");
        assert_flat(&img, [10, 20, 30], 0);
        assert!(to_rgb(PixelFormat::Rgb3, 2, 2, 8, &b[..13]).is_err());
    }

    fn mosaic(order: BayerOrder, w: usize, h: usize, stride: usize, rgb: [u8; 3]) -> Vec<u8> {
        let mut b = vec![0xee; stride * h];
        for y in 0..h {
            for x in 0..w {
                b[y * stride + x] = rgb[order.channel(x, y)];
            }
        }
        b
    }

    #[test]
    fn bayer_flat_colour_demosaics_to_that_colour() {
        for order in [
            BayerOrder::Bggr,
            BayerOrder::Gbrg,
            BayerOrder::Grbg,
            BayerOrder::Rggb,
        ] {
            let rgb = [200, 120, 40];
            let b = mosaic(order, 6, 5, 8, rgb);
            let img = to_rgb(PixelFormat::Bayer(order), 6, 5, 8, &b).expect("converts");
            assert_flat(&img, rgb, 1);
        }
        let order = BayerOrder::Rggb;
        assert_eq!(order.channel(0, 0), 0);
        assert_eq!(order.channel(1, 1), 2);
        assert!(to_rgb(PixelFormat::Bayer(order), 1, 4, 0, &[0; 4]).is_err());
        assert!(to_rgb(PixelFormat::Bayer(order), 6, 5, 8, &[0; 37]).is_err());
        assert!(
            to_rgb(PixelFormat::Bayer(order), 6, 5, 8, &[0; 38]).is_ok(),
            "last row unpadded"
        );
    }

    #[test]
    fn bayer_interpolates_between_samples() {
        // RGGB 4x2 with red samples 0 and 100 at x = 0 and 2: red at x = 1 is their mean.
        let b = [0, 9, 100, 9, 9, 0, 9, 0];
        let img = to_rgb(PixelFormat::Bayer(BayerOrder::Rggb), 4, 2, 0, &b).expect("converts");
        assert_eq!(img.at(1, 0, 0), 50);
        assert_eq!(img.at(1, 0, 1), 9);
    }

    #[test]
    fn mjpg_decodes_and_checks_its_size() {
        let src = image::RgbImage::from_pixel(16, 8, image::Rgb([200, 60, 30]));
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&src)
            .expect("encodes");
        let img = to_rgb(PixelFormat::Mjpg, 16, 8, 0, &jpeg).expect("decodes");
        assert_flat(&img, [200, 60, 30], 6);
        let e = to_rgb(PixelFormat::Mjpg, 32, 8, 0, &jpeg).expect_err("wrong size");
        assert!(
            e.contains("decodes to 16x8, not the negotiated 32x8"),
            "{e}"
        );
        assert!(to_rgb(PixelFormat::Mjpg, 16, 8, 0, &jpeg[..20]).is_err());
    }
}
