//! Pixel formats: which to ask the driver for, and turning a buffer of one into RGB.

use crate::develop::raw::Packing;
pub use crate::develop::BayerOrder;
use crate::develop::{Developer, RawFrame, RawLayout};
use crate::stack::image::Image;

/// The formats focusd converts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    Yuyv,
    Uyvy,
    Nv12,
    /// NV12 with luma and chroma in two memory planes (`NM12`, multi-planar API only).
    Nv12m,
    Mjpg,
    Rgb3,
    /// Raw Bayer, developed by [`crate::develop`].
    Bayer(BayerOrder, Packing),
}

const ORDERS: [BayerOrder; 4] = [
    BayerOrder::Bggr,
    BayerOrder::Gbrg,
    BayerOrder::Grbg,
    BayerOrder::Rggb,
];

const PACKINGS: [Packing; 4] = [
    Packing::Bits8,
    Packing::Mipi10,
    Packing::Le10,
    Packing::Le16,
];

const ALL: [PixelFormat; 22] = {
    let mut all = [PixelFormat::Rgb3; 22];
    let others = [
        PixelFormat::Yuyv,
        PixelFormat::Uyvy,
        PixelFormat::Nv12,
        PixelFormat::Nv12m,
        PixelFormat::Mjpg,
    ];
    let mut i = 0;
    while i < others.len() {
        all[i + 1] = others[i];
        i += 1;
    }
    let mut k = 0;
    while k < 16 {
        all[6 + k] = PixelFormat::Bayer(ORDERS[k % 4], PACKINGS[k / 4]);
        k += 1;
    }
    all
};

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
            PixelFormat::Bayer(order, packing) => bayer_fourcc(order, packing),
        }
    }

    /// A fourcc as the config writes it: exactly, else case-insensitively where that names
    /// one format (`pgAA` and `pGAA` are two).
    pub fn parse(s: &str) -> Result<PixelFormat, String> {
        let name = |f: &PixelFormat| fourcc_str(&f.fourcc());
        if let Some(f) = ALL.iter().find(|f| name(f) == s) {
            return Ok(*f);
        }
        let like: Vec<&PixelFormat> = ALL
            .iter()
            .filter(|f| name(f).eq_ignore_ascii_case(s))
            .collect();
        match like.as_slice() {
            [f] => Ok(**f),
            [] => Err(format!(
                "not a format focusd converts; it converts {}",
                supported()
            )),
            many => {
                let names: Vec<String> = many.iter().map(|f| name(f)).collect();
                Err(format!(
                    "ambiguous: {} differ only in case; give the fourcc exactly",
                    names.join(" and ")
                ))
            }
        }
    }

    /// The bits per sample of a raw Bayer format; `None` for formats an ISP produced.
    pub fn raw_bits(self) -> Option<u32> {
        match self {
            PixelFormat::Bayer(_, packing) => Some(packing.bits()),
            _ => None,
        }
    }

    /// Lower is better. Focus measures and registration want every pixel's own detail:
    /// RGB3 needs no conversion; YUYV/UYVY keep full-resolution luma losslessly (chroma is
    /// halved only horizontally); NV12 halves chroma both ways; MJPG adds block artefacts that
    /// look like texture to a focus measure; raw Bayer is developed here, without the lens
    /// shading and noise reduction an ISP would add, deeper samples first.
    pub fn rank(self) -> u8 {
        match self {
            PixelFormat::Rgb3 => 0,
            PixelFormat::Yuyv | PixelFormat::Uyvy => 1,
            PixelFormat::Nv12 | PixelFormat::Nv12m => 2,
            PixelFormat::Mjpg => 3,
            PixelFormat::Bayer(_, Packing::Bits8) => 5,
            PixelFormat::Bayer(..) => 4,
        }
    }
}

/// V4L2's fourcc of a Bayer format (videodev2.h).
const fn bayer_fourcc(order: BayerOrder, packing: Packing) -> &'static [u8; 4] {
    use BayerOrder::*;
    match (packing, order) {
        (Packing::Bits8, Bggr) => b"BA81",
        (Packing::Bits8, Gbrg) => b"GBRG",
        (Packing::Bits8, Grbg) => b"GRBG",
        (Packing::Bits8, Rggb) => b"RGGB",
        (Packing::Mipi10, Bggr) => b"pBAA",
        (Packing::Mipi10, Gbrg) => b"pGAA",
        (Packing::Mipi10, Grbg) => b"pgAA",
        (Packing::Mipi10, Rggb) => b"pRAA",
        (Packing::Le10, Bggr) => b"BG10",
        (Packing::Le10, Gbrg) => b"GB10",
        (Packing::Le10, Grbg) => b"BA10",
        (Packing::Le10, Rggb) => b"RG10",
        (Packing::Le16, Bggr) => b"BYR2",
        (Packing::Le16, Gbrg) => b"GB16",
        (Packing::Le16, Grbg) => b"GR16",
        (Packing::Le16, Rggb) => b"RG16",
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
    raw_dev: &mut Developer,
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
        (_, &[(bytes, stride)]) => to_rgb(fmt, width, height, stride, bytes, raw_dev),
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
    if !width.is_multiple_of(2) || !height.is_multiple_of(2) {
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
/// packed); for NV12 (and NM12's planes laid end to end) it applies to both planes. Raw Bayer
/// is developed by `raw_dev` (its black level and colour matrix; the first raw frame locks its
/// white balance). A buffer too short for the geometry is an error.
pub fn to_rgb(
    fmt: PixelFormat,
    width: usize,
    height: usize,
    stride: usize,
    bytes: &[u8],
    raw_dev: &mut Developer,
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
            if !width.is_multiple_of(2) {
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
        PixelFormat::Bayer(order, packing) => {
            let raw = copy_raw((order, packing), (width, height), (bytes, stride), raw_dev)?;
            let m = raw.mosaic().map_err(|e| format!("{name}: {e}"))?;
            return Ok(raw_dev.develop(m));
        }
    }
    Ok(Image::from_vec(width, height, 3, out))
}

/// A raw Bayer frame copied from its buffer as it is, to be developed with `dev`'s black
/// level and colour matrix; the error names the format.
pub fn copy_raw(
    (order, packing): (BayerOrder, Packing),
    (width, height): (usize, usize),
    (bytes, stride): (&[u8], usize),
    dev: &Developer,
) -> Result<RawFrame, String> {
    let layout = RawLayout {
        packing,
        width,
        height,
        stride,
        order,
        black_level: dev.black_level,
        matrix: dev.matrix,
    };
    RawFrame::copy(bytes, layout).map_err(|e| {
        let name = fourcc_str(&PixelFormat::Bayer(order, packing).fourcc());
        format!("{name}: {e}")
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::develop::{srgb_encode, IDENTITY};

    /// Raw frames developed with no black level, no colour correction and white balance locked
    /// at 1, so that a test sees the samples' own colours (sRGB-encoded).
    fn neutral() -> Developer {
        Developer {
            black_level: 0,
            matrix: IDENTITY,
            white_balance: Some([1.0; 3]),
        }
    }

    fn rgb(
        f: PixelFormat,
        w: usize,
        h: usize,
        stride: usize,
        b: &[u8],
    ) -> Result<Image<u8>, String> {
        to_rgb(f, w, h, stride, b, &mut neutral())
    }

    fn rgb_planes(
        f: PixelFormat,
        w: usize,
        h: usize,
        p: &[(&[u8], usize)],
    ) -> Result<Image<u8>, String> {
        to_rgb_planes(f, w, h, p, &mut neutral())
    }

    fn assert_flat(img: &Image<u8>, rgb: [u8; 3], tol: u8) {
        for (i, px) in img.data().chunks_exact(3).enumerate() {
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
            Some(PixelFormat::Bayer(BayerOrder::Bggr, Packing::Bits8))
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
            Ok(PixelFormat::Bayer(BayerOrder::Bggr, Packing::Bits8))
        );
        assert_eq!(choose(&[*b"UYVY", *b"RGB3"], None), Ok(PixelFormat::Rgb3));
        assert_eq!(
            choose(&offered, Some("ba81")),
            Ok(PixelFormat::Bayer(BayerOrder::Bggr, Packing::Bits8))
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
            rgb(PixelFormat::Yuyv, 4, 2, 8, &yuyv(4, 2, [126, 128, 128], 8)).expect("converts");
        assert_eq!((grey.width(), grey.height(), grey.channels()), (4, 2, 3));
        assert_flat(&grey, [128, 128, 128], 0);
        // Pure red in BT.601 limited range.
        let red = rgb(PixelFormat::Yuyv, 4, 2, 8, &yuyv(4, 2, [81, 90, 240], 8)).expect("converts");
        assert_flat(&red, [255, 0, 0], 1);
        let black = rgb(PixelFormat::Yuyv, 2, 1, 0, &[16, 128, 16, 128]).expect("converts");
        assert_flat(&black, [0, 0, 0], 0);
    }

    #[test]
    fn yuyv_stride_padding_is_ignored_and_short_buffers_refused() {
        // 0xee padding after each 8-byte line would turn a pixel pink if it were read.
        let img = rgb(
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
        let e = rgb(PixelFormat::Yuyv, 4, 3, 12, &b).expect_err("short");
        assert!(e.contains("too short, 32 needed"), "{e}");
        let e = rgb(PixelFormat::Yuyv, 4, 3, 6, &b).expect_err("narrow stride");
        assert!(e.contains("stride 6 is shorter"), "{e}");
        assert!(
            rgb(PixelFormat::Yuyv, 3, 1, 0, &[0; 8]).is_err(),
            "odd width"
        );
        assert!(rgb(PixelFormat::Yuyv, 0, 1, 0, &[]).is_err(), "empty");
    }

    #[test]
    fn uyvy_red() {
        let b = [90u8, 81, 240, 81].repeat(4);
        let img = rgb(PixelFormat::Uyvy, 4, 2, 0, &b).expect("converts");
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
        let img = rgb(PixelFormat::Nv12, w, h, stride, &b).expect("converts");
        assert_flat(&img, [255, 0, 0], 1);
        let e = rgb(PixelFormat::Nv12, w, h, stride, &b[..stride * h + 3])
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
        let img2 = rgb_planes(PixelFormat::Nv12m, w, h, &planes).expect("converts");
        assert_eq!(img2.data(), img.data());
        let e = rgb_planes(PixelFormat::Nv12m, w, h, &planes[..1]).expect_err("one plane");
        assert!(e.contains("1 memory planes, 2 expected"), "{e}");
        let e = rgb_planes(PixelFormat::Nv12m, w, h, &[planes[0], (&packed[..5], w)])
            .expect_err("short chroma");
        assert!(e.contains("too short"), "{e}");
        // A one-plane format through the planes API is the single-buffer conversion.
        let yuyv = [126u8, 128, 126, 128];
        assert_eq!(
            rgb_planes(PixelFormat::Yuyv, 2, 1, &[(&yuyv[..], 4)]),
            rgb(PixelFormat::Yuyv, 2, 1, 4, &yuyv)
        );
        assert!(rgb_planes(PixelFormat::Yuyv, 2, 1, &planes).is_err());
    }

    #[test]
    fn rgb3_honours_stride() {
        let mut b = vec![0xee; 2 * 8];
        for row in 0..2 {
            b[row * 8..][..6].copy_from_slice(&[10, 20, 30, 10, 20, 30]);
        }
        let img = rgb(PixelFormat::Rgb3, 2, 2, 8, &b).expect("converts");
        assert_flat(&img, [10, 20, 30], 0);
        assert!(rgb(PixelFormat::Rgb3, 2, 2, 8, &b[..13]).is_err());
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

    /// The 8-bit sRGB code of a linear sample `v` of `max`.
    fn enc(v: u16, max: f32) -> u8 {
        (srgb_encode(f32::from(v) / max) * 255.0 + 0.5) as u8
    }

    const ORDERS: [BayerOrder; 4] = [
        BayerOrder::Bggr,
        BayerOrder::Gbrg,
        BayerOrder::Grbg,
        BayerOrder::Rggb,
    ];

    #[test]
    fn bayer_flat_colour_develops_to_that_colour() {
        for order in ORDERS {
            let b = mosaic(order, 6, 5, 8, [200, 120, 40]);
            let img =
                rgb(PixelFormat::Bayer(order, Packing::Bits8), 6, 5, 8, &b).expect("converts");
            assert_flat(&img, [enc(200, 255.0), enc(120, 255.0), enc(40, 255.0)], 1);
        }
        let f = PixelFormat::Bayer(BayerOrder::Rggb, Packing::Bits8);
        assert!(rgb(f, 1, 4, 0, &[0; 4]).is_err());
        let e = rgb(f, 6, 5, 8, &[0; 37]).expect_err("short");
        assert_eq!(
            e,
            "RGGB: 6x5 frame: buffer of 37 bytes is too short, 38 needed"
        );
        assert!(rgb(f, 6, 5, 8, &[0; 38]).is_ok(), "last row unpadded");
    }

    /// A flat colour (10-bit samples) in every raw packing.
    fn raw_buffer(
        packing: Packing,
        order: BayerOrder,
        w: usize,
        h: usize,
        rgb: [u16; 3],
    ) -> Vec<u8> {
        // The 10-bit samples at the packing's depth.
        let at_depth = |v: u16| match packing.bits() {
            8 => v >> 2,
            16 => v << 6,
            _ => v,
        };
        let samples: Vec<u16> = (0..w * h)
            .map(|i| at_depth(rgb[order.channel(i % w, i / w)]))
            .collect();
        crate::develop::raw::pack(packing, w, &samples)
    }

    #[test]
    fn every_raw_packing_develops_the_same_colour() {
        let rgb10 = [803, 402, 97];
        for order in ORDERS {
            for packing in PACKINGS {
                let f = PixelFormat::Bayer(order, packing);
                assert_eq!(PixelFormat::from_fourcc(&f.fourcc()), Some(f));
                let b = raw_buffer(packing, order, 8, 4, rgb10);
                let img = rgb(f, 8, 4, 0, &b).unwrap_or_else(|e| panic!("{f:?}: {e}"));
                let want = match packing {
                    Packing::Bits8 => rgb10.map(|v| enc(v >> 2, 255.0)),
                    _ => rgb10.map(|v| enc(v, 1023.0)),
                };
                assert_flat(&img, want, 1);
            }
        }
        // The profile's black level comes off before anything else: a pedestal of 64 (10-bit)
        // under a grey of 64 + 480 develops to the grey 480 of 959.
        let f = PixelFormat::Bayer(BayerOrder::Rggb, Packing::Mipi10);
        let b = raw_buffer(Packing::Mipi10, BayerOrder::Rggb, 8, 4, [544; 3]);
        let mut dev = Developer {
            black_level: 64,
            ..neutral()
        };
        let img = to_rgb(f, 8, 4, 0, &b, &mut dev).expect("converts");
        let want = (srgb_encode(480.0 / 959.0) * 255.0 + 0.5) as u8;
        assert_flat(&img, [want; 3], 0);
    }

    #[test]
    fn fourccs_that_differ_only_in_case_need_the_exact_case() {
        assert_eq!(
            PixelFormat::parse("pgAA"),
            Ok(PixelFormat::Bayer(BayerOrder::Grbg, Packing::Mipi10))
        );
        assert_eq!(
            PixelFormat::parse("pGAA"),
            Ok(PixelFormat::Bayer(BayerOrder::Gbrg, Packing::Mipi10))
        );
        let e = PixelFormat::parse("pgaa").expect_err("ambiguous");
        assert_eq!(
            e,
            "ambiguous: pGAA and pgAA differ only in case; give the fourcc exactly"
        );
        assert_eq!(
            PixelFormat::parse("praa"),
            Ok(PixelFormat::Bayer(BayerOrder::Rggb, Packing::Mipi10))
        );
        assert_eq!(
            PixelFormat::parse("rg10").map(PixelFormat::raw_bits),
            Ok(Some(10))
        );
    }

    #[test]
    fn mjpg_decodes_and_checks_its_size() {
        let src = image::RgbImage::from_pixel(16, 8, image::Rgb([200, 60, 30]));
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&src)
            .expect("encodes");
        let img = rgb(PixelFormat::Mjpg, 16, 8, 0, &jpeg).expect("decodes");
        assert_flat(&img, [200, 60, 30], 6);
        let e = rgb(PixelFormat::Mjpg, 32, 8, 0, &jpeg).expect_err("wrong size");
        assert!(
            e.contains("decodes to 16x8, not the negotiated 32x8"),
            "{e}"
        );
        assert!(rgb(PixelFormat::Mjpg, 16, 8, 0, &jpeg[..20]).is_err());
    }
}
