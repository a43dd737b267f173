//! Choosing a shipped device profile when `[camera] profile` names none, as Megapixels picks
//! its config: by the device-tree compatible, most specific first (a phone's model, then its
//! SoC's); else, for profiles no device tree names (vimc), by a media device's model. A phone's
//! media model is its SoC's (`rkisp1` on every RK3399 board), so it never picks a phone's
//! profile by itself.
//!
//! Both come from sysfs, under the `[camera] sysfs_root` (so tests use a fake tree):
//! `firmware/devicetree/base/compatible` (what `/proc/device-tree/compatible` links to:
//! NUL-separated strings) and `bus/media/devices/media*/model`.

use super::profile::{Profile, SHIPPED};
use std::fs;
use std::path::Path;

/// A profile chosen, and what chose it (for the log and for errors).
#[derive(Clone, Debug, PartialEq)]
pub struct Choice {
    pub profile: Profile,
    pub reason: String,
}

/// The shipped profile for this machine, if one fits.
pub fn detect(sysfs_root: &Path) -> Result<Option<Choice>, String> {
    let compatible = compatibles(sysfs_root);
    let models = media_models(sysfs_root);
    choose(&compatible, &models)
}

/// The device tree's compatible strings, most specific first; none without a device tree.
fn compatibles(sysfs_root: &Path) -> Vec<String> {
    fs::read(sysfs_root.join("firmware/devicetree/base/compatible"))
        .map(|bytes| {
            bytes
                .split(|&b| b == 0)
                .filter(|s| !s.is_empty())
                .map(|s| String::from_utf8_lossy(s).into_owned())
                .collect()
        })
        .unwrap_or_default()
}

/// The models of the media devices, in the order of their names.
fn media_models(sysfs_root: &Path) -> Vec<String> {
    let Ok(dir) = fs::read_dir(sysfs_root.join("bus/media/devices")) else {
        return Vec::new();
    };
    let mut found: Vec<(String, String)> = dir
        .flatten()
        .filter_map(|e| {
            let model = fs::read_to_string(e.path().join("model")).ok()?;
            Some((
                e.file_name().to_string_lossy().into_owned(),
                model.trim_end_matches('\n').to_string(),
            ))
        })
        .collect();
    found.sort();
    found.into_iter().map(|(_, m)| m).collect()
}

/// The pure choice, from the compatibles and the media models.
fn choose(compatible: &[String], models: &[String]) -> Result<Option<Choice>, String> {
    let shipped = SHIPPED
        .iter()
        .map(|(name, text)| Profile::parse(text, name))
        .collect::<Result<Vec<Profile>, String>>()?;
    for c in compatible {
        if let Some(p) = shipped.iter().find(|p| p.compatible.contains(c)) {
            return Ok(Some(Choice {
                profile: p.clone(),
                reason: format!("the device-tree compatible {c:?}"),
            }));
        }
    }
    for m in models {
        if let Some(p) = shipped
            .iter()
            .find(|p| p.compatible.is_empty() && p.media_model == *m)
        {
            return Ok(Some(Choice {
                profile: p.clone(),
                reason: format!("the media device model {m:?}"),
            }));
        }
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strings(s: &[&str]) -> Vec<String> {
        s.iter().map(|s| s.to_string()).collect()
    }

    fn chosen(compatible: &[&str], models: &[&str]) -> Option<(String, String)> {
        choose(&strings(compatible), &strings(models))
            .expect("shipped profiles parse")
            .map(|c| (c.profile.name, c.reason))
    }

    #[test]
    fn phones_are_chosen_by_their_device_tree_compatible() {
        let pro = chosen(&["pine64,pinephone-pro", "rockchip,rk3399"], &["rkisp1"]);
        assert_eq!(
            pro,
            Some((
                "pinephone-pro".into(),
                "the device-tree compatible \"pine64,pinephone-pro\"".into()
            ))
        );
        let name = |c: &[&str]| chosen(c, &[]).map(|(n, _)| n);
        assert_eq!(
            name(&[
                "pine64,pinephone-1.2",
                "pine64,pinephone",
                "allwinner,sun50i-a64"
            ])
            .as_deref(),
            Some("pinephone")
        );
        assert_eq!(
            name(&["purism,librem5r4", "purism,librem5", "fsl,imx8mq"]).as_deref(),
            Some("librem5")
        );
        assert_eq!(
            name(&["oneplus,fajita", "qcom,sdm845"]).as_deref(),
            Some("oneplus6")
        );
        // Whole strings only: the PinePhone's "pine64,pinephone" is no prefix of the Pro's.
        assert_eq!(
            name(&["pine64,pinephone-pro"]).as_deref(),
            Some("pinephone-pro")
        );
    }

    #[test]
    fn a_soc_or_media_model_alone_picks_no_phone() {
        // Another RK3399 board: its SoC compatible and rkisp1's model are the Pro's too.
        assert_eq!(
            chosen(&["radxa,rockpi4b", "rockchip,rk3399"], &["rkisp1"]),
            None
        );
        assert_eq!(
            chosen(&[], &["imx-media", "Qualcomm Camera Subsystem"]),
            None
        );
        assert_eq!(chosen(&[], &[]), None);
        // vimc, which no device tree names, by its model, after the machine's own devices.
        assert_eq!(
            chosen(&["qemu,virt"], &["uvcvideo", "VIMC MDEV"]),
            Some(("vimc".into(), "the media device model \"VIMC MDEV\"".into()))
        );
        // A device-tree match comes before a model match.
        assert_eq!(
            chosen(&["pine64,pinephone-pro"], &["VIMC MDEV"]).map(|(n, _)| n),
            Some("pinephone-pro".into())
        );
    }

    #[test]
    fn detection_reads_a_sysfs_tree() {
        let t = tempfile::tempdir().expect("tempdir");
        let root = t.path().join("sys");
        assert_eq!(detect(&root), Ok(None), "no tree at all");
        let dt = root.join("firmware/devicetree/base");
        fs::create_dir_all(&dt).expect("mkdir");
        fs::write(
            dt.join("compatible"),
            b"purism,librem5r3\0purism,librem5\0fsl,imx8mq\0",
        )
        .expect("write");
        let c = detect(&root).expect("reads").expect("chosen");
        assert_eq!(c.profile.name, "librem5");
        assert_eq!(c.reason, "the device-tree compatible \"purism,librem5r3\"");
        fs::write(dt.join("compatible"), b"qemu,virt\0").expect("write");
        for (dev, model) in [("media1", "VIMC MDEV\n"), ("media0", "vivid\n")] {
            let d = root.join("bus/media/devices").join(dev);
            fs::create_dir_all(&d).expect("mkdir");
            fs::write(d.join("model"), model).expect("write");
        }
        assert_eq!(media_models(&root), strings(&["vivid", "VIMC MDEV"]));
        let c = detect(&root).expect("reads").expect("chosen");
        assert_eq!(c.profile.name, "vimc");
    }
}
