//! What the sensor reports, turned into the pipeline's formats: a Bayer media-bus code is an
//! order and a bit depth; a profile names only the depth (`BAYER10`), and the order is the one
//! the sensor offers (which on the imx258 follows its flip controls). Pure: the device calls
//! are in [`super::pipeline`].

use super::format::PixelFormat;
use crate::backend::videodev::subdev::SizeRange;
use crate::develop::raw::Packing;
use crate::develop::BayerOrder;

/// The Bayer media-bus codes focusd follows: (order, bits, code), from `v4l2-mediabus.h`.
const BAYER_CODES: [(BayerOrder, u32, u32); 8] = [
    (BayerOrder::Bggr, 8, 0x3001),
    (BayerOrder::Grbg, 8, 0x3002),
    (BayerOrder::Gbrg, 8, 0x3013),
    (BayerOrder::Rggb, 8, 0x3014),
    (BayerOrder::Bggr, 10, 0x3007),
    (BayerOrder::Grbg, 10, 0x300a),
    (BayerOrder::Gbrg, 10, 0x300e),
    (BayerOrder::Rggb, 10, 0x300f),
];

/// The depths a profile may name.
pub const DEPTHS: [u32; 2] = [8, 10];

/// The code of a Bayer order at a depth.
pub fn bayer_code(order: BayerOrder, bits: u32) -> Option<u32> {
    BAYER_CODES
        .iter()
        .find(|&&(o, b, _)| o == order && b == bits)
        .map(|&(_, _, c)| c)
}

/// The order and depth of a Bayer code; `None` for other codes.
pub fn bayer_of(code: u32) -> Option<(BayerOrder, u32)> {
    BAYER_CODES
        .iter()
        .find(|&&(_, _, c)| c == code)
        .map(|&(o, b, _)| (o, b))
}

/// A profile's depth-only Bayer code, `BAYER8` or `BAYER10`: its depth.
pub fn depth_token(name: &str) -> Option<u32> {
    let bits: u32 = name.strip_prefix("BAYER")?.parse().ok()?;
    DEPTHS.contains(&bits).then_some(bits)
}

/// The capture node's format for the sensor's order at `bits` (one byte or one 16-bit word a
/// sample, as ISPs and bridges write Bayer to memory).
pub fn capture_format(order: BayerOrder, bits: u32) -> PixelFormat {
    let packing = if bits <= 8 {
        Packing::Bits8
    } else {
        Packing::Le10
    };
    PixelFormat::Bayer(order, packing)
}

/// The Bayer code at `bits` to stream: the sensor's current one when it is such a code (a
/// sensor offering every order, as vimc's, keeps what it was set to), else the first one the
/// sensor offers. The error lists what it offers.
pub fn choose_code(offered: &[u32], current: Option<u32>, bits: u32) -> Result<u32, String> {
    let fits = |c: &u32| bayer_of(*c).is_some_and(|(_, b)| b == bits);
    if let Some(c) = current.filter(|c| offered.contains(c) && fits(c)) {
        return Ok(c);
    }
    offered.iter().copied().find(fits).ok_or_else(|| {
        let names: Vec<String> = offered
            .iter()
            .map(|&c| super::profile::mbus_name(c))
            .collect();
        format!(
            "it offers no {bits}-bit Bayer code, only {}: set the profile's [mode] bits to \
             the depth it offers",
            if names.is_empty() {
                "none".to_string()
            } else {
                names.join(", ")
            }
        )
    })
}

/// The profile's preferred sizes the sensor offers (one of its modes, or within its range), in
/// the profile's order; the error lists what it offers.
pub fn offered_modes(wanted: &[[u32; 2]], offered: &[SizeRange]) -> Result<Vec<[u32; 2]>, String> {
    let within = |[w, h]: [u32; 2]| {
        offered
            .iter()
            .any(|&((lw, lh), (hw, hh))| (lw..=hw).contains(&w) && (lh..=hh).contains(&h))
    };
    let modes: Vec<[u32; 2]> = wanted.iter().copied().filter(|&m| within(m)).collect();
    if modes.is_empty() {
        let sizes: Vec<String> = offered
            .iter()
            .map(|&((lw, lh), (hw, hh))| {
                if (lw, lh) == (hw, hh) {
                    format!("{hw}x{hh}")
                } else {
                    format!("{lw}x{lh} to {hw}x{hh}")
                }
            })
            .collect();
        let asked: Vec<String> = wanted.iter().map(|[w, h]| format!("{w}x{h}")).collect();
        return Err(format!(
            "it offers {}, none of the profile's [mode] sizes {}",
            if sizes.is_empty() {
                "no sizes".to_string()
            } else {
                sizes.join(", ")
            },
            asked.join(", ")
        ));
    }
    Ok(modes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::v4l2::profile::mbus_code;

    #[test]
    fn codes_name_their_order_and_depth() {
        for (order, bits, code) in BAYER_CODES {
            assert_eq!(bayer_code(order, bits), Some(code));
            assert_eq!(bayer_of(code), Some((order, bits)));
        }
        assert_eq!(mbus_code("SBGGR10_1X10"), bayer_code(BayerOrder::Bggr, 10));
        assert_eq!(mbus_code("SGRBG8_1X8"), bayer_code(BayerOrder::Grbg, 8));
        assert_eq!(bayer_of(0x100a), None);
        assert_eq!(depth_token("BAYER10"), Some(10));
        assert_eq!(depth_token("BAYER8"), Some(8));
        assert_eq!(depth_token("BAYER12"), None);
        assert_eq!(depth_token("SRGGB8_1X8"), None);
        assert_eq!(
            capture_format(BayerOrder::Grbg, 8).fourcc(),
            *b"GRBG",
            "8-bit GRBG"
        );
        assert_eq!(capture_format(BayerOrder::Bggr, 10).fourcc(), *b"BG10");
    }

    #[test]
    fn the_order_comes_from_the_sensor() {
        let bggr10 = 0x3007;
        // imx258 since 6.11: one code, the flipped order.
        assert_eq!(choose_code(&[bggr10], None, 10), Ok(bggr10));
        // vimc: every order; the one it was set to is kept.
        let all = [0x100a, 0x3001, 0x3002, 0x3013, 0x3014];
        assert_eq!(choose_code(&all, Some(0x3013), 8), Ok(0x3013));
        assert_eq!(choose_code(&all, Some(0x100a), 8), Ok(0x3001));
        assert_eq!(choose_code(&all, None, 8), Ok(0x3001));
        let e = choose_code(&[bggr10], None, 8).expect_err("no 8-bit");
        assert_eq!(
            e,
            "it offers no 8-bit Bayer code, only SBGGR10_1X10: set the profile's [mode] bits \
             to the depth it offers"
        );
    }

    #[test]
    fn modes_keep_the_profiles_preference() {
        let imx258 = [(4208, 3120), (2104, 1560), (1048, 780)].map(|s| (s, s));
        assert_eq!(
            offered_modes(&[[2104, 1560], [4208, 3120]], &imx258),
            Ok(vec![[2104, 1560], [4208, 3120]])
        );
        let e = offered_modes(&[[640, 480]], &imx258).expect_err("none");
        assert_eq!(
            e,
            "it offers 4208x3120, 2104x1560, 1048x780, none of the profile's [mode] sizes 640x480"
        );
        // vimc's sensor: one range.
        let vimc = [((16, 16), (4096, 2160))];
        assert_eq!(offered_modes(&[[640, 480]], &vimc), Ok(vec![[640, 480]]));
        let e = offered_modes(&[[8192, 480]], &vimc).expect_err("too wide");
        assert!(e.starts_with("it offers 16x16 to 4096x2160, none"), "{e}");
    }
}
