//! The replay bundle: a directory with `bundle.toml` (the takes), their image files and
//! `imu.csv` (the IMU trace). `focusd record` writes it on a phone, the simulator writes
//! synthetic ones, and the replay backends serve it. Both files are parsed defensively: they may
//! come from another machine.

use crate::capture::{ImuSample, Nanos, Sensor};
use crate::files::outputs::{write_atomic, StagedDir};
use crate::files::FileError;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::io::{BufRead, Read as _};
use std::path::{Component, Path, PathBuf};

/// The current format version, written as `format = 1`.
pub const FORMAT: u32 = 1;
/// Largest `imu.csv` read (an hour at 1 kHz of both sensors is ~250 MB; a sweep is seconds).
const MAX_CSV_BYTES: u64 = 64 << 20;
const MAX_TAKES: usize = 4096;

/// `bundle.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format: u32,
    /// The lens range of the camera that recorded it.
    pub lens_min: i32,
    pub lens_max: i32,
    /// The sensor's rotation (degrees counter-clockwise that make its pictures upright, as
    /// V4L2_CID_CAMERA_SENSOR_ROTATION): 0, 90, 180 or 270.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub rotation: i64,
    /// Every take in capture order.
    pub takes: Vec<TakeEntry>,
}

/// One `[[takes]]` entry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TakeEntry {
    /// Focus plane, 0 = nearest.
    pub plane: usize,
    pub lens: i32,
    /// Image file, relative to the bundle directory.
    pub image: String,
    pub exposure_start_ns: Nanos,
    pub exposure_end_ns: Nanos,
}

/// A parsed, checked bundle.
#[derive(Clone, Debug)]
pub struct Bundle {
    pub dir: PathBuf,
    /// `dir` with every link resolved: the files read must lie under it.
    root: PathBuf,
    pub manifest: Manifest,
    /// Sorted by time.
    pub imu: Vec<ImuSample>,
}

/// Why a bundle cannot be read; the message names the file (and line) and the problem.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {reason}")]
pub struct BundleError {
    pub path: String,
    pub reason: String,
}

/// Why a bundle cannot be written.
#[derive(Debug, thiserror::Error)]
pub enum BundleWriteError {
    #[error("{dir}: cannot create the directory")]
    CreateDir {
        dir: String,
        #[source]
        error: std::io::Error,
    },
    #[error("{file}: not a file in {dir}")]
    NotInBundle { file: String, dir: String },
    #[error("encoding bundle.toml")]
    Manifest(#[source] toml::ser::Error),
    #[error(transparent)]
    File(#[from] FileError),
}

fn err(path: &Path, reason: impl Into<String>) -> BundleError {
    BundleError {
        path: path.display().to_string(),
        reason: reason.into(),
    }
}

impl Bundle {
    pub fn open(dir: &Path) -> Result<Bundle, BundleError> {
        let root = dir
            .canonicalize()
            .map_err(|e| err(dir, format!("cannot open the bundle: {e}")))?;
        let toml_path = dir.join("bundle.toml");
        let text = crate::files::bounded_read::read_to_string(
            &inside(&root, &toml_path)?,
            crate::files::bounded_read::TEXT_CAP,
        )
        .map_err(|e| err(&toml_path, format!("cannot read: {e}")))?;
        let manifest = parse_manifest(&text).map_err(|r| err(&toml_path, r))?;
        let csv_path = dir.join("imu.csv");
        let imu = read_imu(&inside(&root, &csv_path)?)?;
        Ok(Bundle {
            dir: dir.to_path_buf(),
            root,
            manifest,
            imu,
        })
    }

    /// The path of a file the manifest names, once it is known to resolve inside the bundle.
    pub fn file(&self, name: &str) -> Result<PathBuf, BundleError> {
        inside(&self.root, &self.dir.join(name))
    }

    /// Planes recorded: one more than the largest plane index.
    pub fn planes(&self) -> usize {
        self.manifest
            .takes
            .iter()
            .map(|t| t.plane + 1)
            .max()
            .unwrap_or(0)
    }

    /// The lens position recorded for each plane (its first take's).
    pub fn lens_positions(&self) -> Vec<i32> {
        (0..self.planes())
            .map(|p| {
                self.manifest
                    .takes
                    .iter()
                    .find(|t| t.plane == p)
                    .map_or(0, |t| t.lens)
            })
            .collect()
    }
}

/// Parses and checks `bundle.toml`; the error says what is wrong and where.
fn is_zero(v: &i64) -> bool {
    *v == 0
}

pub fn parse_manifest(text: &str) -> Result<Manifest, String> {
    let m: Manifest = toml::from_str(text).map_err(|e| e.to_string().trim().to_string())?;
    if m.format != FORMAT {
        return Err(format!(
            "format = {} is not supported (this focusd reads format {FORMAT})",
            m.format
        ));
    }
    if m.lens_min > m.lens_max {
        return Err(format!(
            "lens_min = {} is above lens_max = {}",
            m.lens_min, m.lens_max
        ));
    }
    if ![0, 90, 180, 270].contains(&m.rotation) {
        return Err(format!(
            "rotation = {}: give 0, 90, 180 or 270 (degrees counter-clockwise)",
            m.rotation
        ));
    }
    if m.takes.is_empty() {
        return Err("no [[takes]]".into());
    }
    if m.takes.len() > MAX_TAKES {
        return Err(format!("{} takes, more than {MAX_TAKES}", m.takes.len()));
    }
    for (i, t) in m.takes.iter().enumerate() {
        let at = format!("take {i} (plane {}, {})", t.plane, t.image);
        if t.plane >= MAX_TAKES {
            return Err(format!(
                "{at}: plane {} is beyond the {MAX_TAKES} a bundle can hold",
                t.plane
            ));
        }
        if t.exposure_end_ns <= t.exposure_start_ns {
            return Err(format!(
                "{at}: exposure_end_ns {} is not after exposure_start_ns {}",
                t.exposure_end_ns, t.exposure_start_ns
            ));
        }
        if !(m.lens_min..=m.lens_max).contains(&t.lens) {
            return Err(format!(
                "{at}: lens {} is outside {}..={}",
                t.lens, m.lens_min, m.lens_max
            ));
        }
        if !is_plain_relative(&t.image) {
            return Err(format!(
                "{at}: image must be a file name inside the bundle, not a path outside it"
            ));
        }
    }
    // One camera exposes one frame at a time.
    let mut by_time: Vec<(usize, &TakeEntry)> = m.takes.iter().enumerate().collect();
    by_time.sort_by_key(|(_, t)| t.exposure_start_ns);
    for w in by_time.windows(2) {
        let ((i, a), (j, b)) = (w[0], w[1]);
        if b.exposure_start_ns < a.exposure_end_ns {
            return Err(format!(
                "takes {i} ({}) and {j} ({}) overlap in time: take {j} starts at {} ns, before \
                 take {i} ends at {} ns",
                a.image, b.image, b.exposure_start_ns, a.exposure_end_ns
            ));
        }
    }
    let planes = m.takes.iter().map(|t| t.plane + 1).max().unwrap_or(0);
    if let Some(p) = (0..planes).find(|&p| !m.takes.iter().any(|t| t.plane == p)) {
        return Err(format!(
            "plane {p} has no take (planes run 0..{planes} without gaps)"
        ));
    }
    Ok(m)
}

/// A relative path that stays inside the directory it is joined to.
fn is_plain_relative(p: &str) -> bool {
    !p.is_empty()
        && Path::new(p)
            .components()
            .all(|c| matches!(c, Component::Normal(_)))
}

/// `path` with its links resolved, if that lies under `root`. The manifest's names are plain
/// relative paths already (`is_plain_relative`), but a file or directory in the bundle may be a link
/// out of it: a bundle handed to the daemon must not make it read (and echo in errors) a file
/// the caller could not name directly.
fn inside(root: &Path, path: &Path) -> Result<PathBuf, BundleError> {
    let real = path
        .canonicalize()
        .map_err(|e| err(path, format!("cannot read: {e}")))?;
    if !real.starts_with(root) {
        return Err(err(
            path,
            format!(
                "resolves to {}, outside the bundle directory {}; a bundle's files must lie \
                 inside it (copy the file in instead of linking to it)",
                real.display(),
                root.display()
            ),
        ));
    }
    Ok(real)
}

fn read_imu(path: &Path) -> Result<Vec<ImuSample>, BundleError> {
    use crate::files::bounded_read::{check_cap, open_capped};
    let cannot = |e: std::io::Error| err(path, format!("cannot read: {e}"));
    let mut r = std::io::BufReader::new(open_capped(path, MAX_CSV_BYTES).map_err(cannot)?);
    let samples = parse_imu(&mut r).map_err(|r| err(path, r))?;
    check_cap(r.get_ref(), MAX_CSV_BYTES).map_err(cannot)?;
    Ok(samples)
}

/// Longest line of `imu.csv`: five numbers and a sensor name take well under 100 bytes; a longer
/// line is refused before it is held whole.
const MAX_CSV_LINE: u64 = 256;

/// Parses `imu.csv` as it streams in: a `t_ns,sensor,x,y,z` header, then one sample per line, time
/// never going backwards. Only one line (at most [`MAX_CSV_LINE`] bytes) is held at a time.
pub fn parse_imu(mut r: impl BufRead) -> Result<Vec<ImuSample>, String> {
    let mut buf = Vec::new();
    let mut n = 0usize;
    let mut next_line = |buf: &mut Vec<u8>| -> Result<Option<usize>, String> {
        buf.clear();
        n += 1;
        let got = (&mut r)
            .take(MAX_CSV_LINE + 1)
            .read_until(b'\n', buf)
            .map_err(|e| format!("line {n}: cannot read: {e}"))?;
        if got == 0 {
            return Ok(None);
        }
        if buf.len() as u64 > MAX_CSV_LINE {
            return Err(format!("line {n}: longer than {MAX_CSV_LINE} bytes"));
        }
        Ok(Some(n))
    };
    let header = match next_line(&mut buf)? {
        Some(_) => std::str::from_utf8(&buf).ok().map(str::trim),
        None => None,
    };
    if header != Some("t_ns,sensor,x,y,z") {
        return Err("line 1: expected the header t_ns,sensor,x,y,z".into());
    }
    let mut out = Vec::new();
    let mut last = Nanos::MIN;
    while let Some(n) = next_line(&mut buf)? {
        let line = std::str::from_utf8(&buf).map_err(|_| format!("line {n}: not UTF-8 text"))?;
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != 5 {
            return Err(format!("line {n}: {} fields, expected 5", f.len()));
        }
        let t: Nanos = f[0]
            .parse()
            .map_err(|_| format!("line {n}: t_ns {:?} is not an integer", f[0]))?;
        if t < last {
            return Err(format!(
                "line {n}: time goes backwards ({t} ns after {last} ns)"
            ));
        }
        last = t;
        let sensor = match f[1] {
            "gyro" => Sensor::Gyro,
            "accel" => Sensor::Accel,
            s => return Err(format!("line {n}: sensor {s:?} is not gyro or accel")),
        };
        let mut v = [0.0; 3];
        for (a, s) in v.iter_mut().zip(&f[2..]) {
            *a = s
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("line {n}: {s:?} is not a finite number"))?;
        }
        out.push(ImuSample { t, sensor, v });
    }
    if out.is_empty() {
        return Err("no samples".into());
    }
    // The motion gate reads both sensors; without one, the still wait would never end.
    for (sensor, name) in [(Sensor::Gyro, "gyro"), (Sensor::Accel, "accel")] {
        if !out.iter().any(|s| s.sensor == sensor) {
            return Err(format!(
                "no {name} samples: the motion gate reads the gyroscope and the accelerometer, \
                 so a trace needs both"
            ));
        }
    }
    Ok(out)
}

/// Writes a bundle: images first, then `imu.csv`, then `bundle.toml` last, each to a temporary
/// file renamed into place, so a bundle with a manifest is complete. A new bundle
/// ([`BundleWriter::create_new`]) is written in a temporary folder renamed into place at the
/// end, so it appears whole or not at all.
pub struct BundleWriter {
    dir: PathBuf,
    staged: Option<StagedDir>,
    manifest: Manifest,
}

impl BundleWriter {
    /// Writes into `dir` (created if missing), beside what is there: the frames `add_existing`
    /// names.
    pub fn create(dir: &Path, lens_range: (i32, i32)) -> Result<BundleWriter, BundleWriteError> {
        std::fs::create_dir_all(dir).map_err(|error| BundleWriteError::CreateDir {
            dir: dir.display().to_string(),
            error,
        })?;
        Ok(Self::writing_to(dir.to_path_buf(), None, lens_range))
    }

    /// Writes a new bundle `dir` (it must not exist, or be an empty folder) through a
    /// temporary folder beside it.
    pub fn create_new(
        dir: &Path,
        lens_range: (i32, i32),
    ) -> Result<BundleWriter, BundleWriteError> {
        let staged = StagedDir::create(dir)?;
        Ok(Self::writing_to(
            staged.writing_dir().to_path_buf(),
            Some(staged),
            lens_range,
        ))
    }

    fn writing_to(dir: PathBuf, staged: Option<StagedDir>, lens_range: (i32, i32)) -> Self {
        BundleWriter {
            dir,
            staged,
            manifest: Manifest {
                format: FORMAT,
                lens_min: lens_range.0,
                lens_max: lens_range.1,
                rotation: 0,
                takes: Vec::new(),
            },
        }
    }

    /// Records the sensor's rotation (degrees counter-clockwise).
    pub fn with_rotation(mut self, degrees: i64) -> BundleWriter {
        self.manifest.rotation = degrees;
        self
    }

    /// Adds a take whose encoded image is `bytes`, named after its plane and take.
    pub fn add_take(
        &mut self,
        plane: usize,
        lens: i32,
        exposure: (Nanos, Nanos),
        extension: &str,
        bytes: &[u8],
    ) -> Result<(), BundleWriteError> {
        let take = self
            .manifest
            .takes
            .iter()
            .filter(|t| t.plane == plane)
            .count();
        let image = format!("plane{plane:02}_take{take}.{extension}");
        write_atomic(&self.dir.join(&image), bytes)?;
        self.manifest.takes.push(TakeEntry {
            plane,
            lens,
            image,
            exposure_start_ns: exposure.0,
            exposure_end_ns: exposure.1,
        });
        Ok(())
    }

    /// Adds a take whose image is already in the bundle directory as `file`.
    pub fn add_existing(
        &mut self,
        plane: usize,
        lens: i32,
        exposure: (Nanos, Nanos),
        file: &str,
    ) -> Result<(), BundleWriteError> {
        if !is_plain_relative(file) || !self.dir.join(file).is_file() {
            return Err(BundleWriteError::NotInBundle {
                file: file.to_string(),
                dir: self.dir.display().to_string(),
            });
        }
        self.manifest.takes.push(TakeEntry {
            plane,
            lens,
            image: file.to_string(),
            exposure_start_ns: exposure.0,
            exposure_end_ns: exposure.1,
        });
        Ok(())
    }

    pub fn finish(self, imu: &[ImuSample]) -> Result<(), BundleWriteError> {
        let mut csv = String::from("t_ns,sensor,x,y,z\n");
        for s in imu {
            let name = match s.sensor {
                Sensor::Gyro => "gyro",
                Sensor::Accel => "accel",
            };
            let [x, y, z] = s.v;
            writeln!(csv, "{},{name},{x},{y},{z}", s.t).expect("writing to a String");
        }
        write_atomic(&self.dir.join("imu.csv"), csv.as_bytes())?;
        let toml = toml::to_string(&self.manifest).map_err(BundleWriteError::Manifest)?;
        let text = format!("# focusd replay bundle: see sim-data/README.md\n{toml}");
        write_atomic(&self.dir.join("bundle.toml"), text.as_bytes())?;
        if let Some(staged) = self.staged {
            staged.commit()?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
format = 1
lens_min = 0
lens_max = 1023
[[takes]]
plane = 0
lens = 1023
image = "a.jpg"
exposure_start_ns = 100
exposure_end_ns = 200
[[takes]]
plane = 1
lens = 0
image = "b.jpg"
exposure_start_ns = 300
exposure_end_ns = 400
"#;

    #[test]
    fn manifest_round_trips_and_bad_ones_say_why() {
        let m = parse_manifest(GOOD).unwrap();
        assert_eq!(m.takes.len(), 2);
        assert_eq!(parse_manifest(&toml::to_string(&m).unwrap()).unwrap(), m);
        let bad = |from: &str, to: &str| parse_manifest(&GOOD.replacen(from, to, 1)).unwrap_err();
        assert!(bad("format = 1", "format = 2").contains("format = 2"));
        assert!(bad("\"a.jpg\"", "\"../x.jpg\"").contains("inside the bundle"));
        assert!(bad("\"a.jpg\"", "\"/etc/passwd\"").contains("inside the bundle"));
        assert!(bad("exposure_end_ns = 200", "exposure_end_ns = 50").contains("not after"));
        assert!(bad("lens = 1023", "lens = 2000").contains("outside 0..=1023"));
        assert!(bad("plane = 1", "plane = 2").contains("plane 1 has no take"));
        assert!(bad("lens_max = 1023", "lens_max = 1023\ncolour = 3").contains("colour"));
        assert!(bad("plane = 0", "plane = -1").contains("plane"));
        let e = bad("exposure_start_ns = 300", "exposure_start_ns = 150");
        assert!(
            e.contains("takes 0 (a.jpg) and 1 (b.jpg) overlap in time"),
            "{e}"
        );
    }

    #[test]
    fn imu_csv_is_checked_line_by_line() {
        let ok = "t_ns,sensor,x,y,z\n1,gyro,0.1,0,0\n1,accel,0,9.8,0\n5,gyro,0,0,0\n";
        assert!(parse_imu("t_ns,sensor,x,y,z\n1,gyro,0.1,0,0\n".as_bytes())
            .unwrap_err()
            .contains("no accel samples"));
        let s = parse_imu(ok.as_bytes()).unwrap();
        assert_eq!(s.len(), 3);
        assert_eq!(s[1].sensor, Sensor::Accel);
        let bad = |t: &str| parse_imu(t.as_bytes()).unwrap_err();
        assert!(bad("t,s,x\n").contains("header"));
        assert!(bad("t_ns,sensor,x,y,z\n5,gyro,0,0,0\n4,gyro,0,0,0\n")
            .contains("line 3: time goes backwards"));
        assert!(bad("t_ns,sensor,x,y,z\n5,gyro,NaN,0,0\n").contains("line 2: \"NaN\""));
        assert!(bad("t_ns,sensor,x,y,z\n5,magnet,0,0,0\n").contains("magnet"));
        assert!(bad("t_ns,sensor,x,y,z\n5,gyro,0,0\n").contains("4 fields"));
        assert!(bad("t_ns,sensor,x,y,z\n").contains("no samples"));
        let long = format!(
            "t_ns,sensor,x,y,z\n1,gyro,0,0,0\n2,gyro,{},0,0\n",
            "0".repeat(300)
        );
        assert!(bad(&long).contains("line 3: longer than 256 bytes"));
        assert!(parse_imu(&b"t_ns,sensor,x,y,z\n1,gyro,0,0,\xff\n"[..])
            .unwrap_err()
            .contains("line 2: not UTF-8"));
    }

    /// A trace of one endless line (as from a file that is all one line) is refused after at most
    /// one line's worth of bytes is held, however long the rest is.
    #[test]
    fn an_endless_line_is_refused_after_the_line_cap() {
        let endless = b"t_ns,sensor,x,y,z\n1,gyro,".chain(std::io::repeat(b'7'));
        let mut counted = std::io::BufReader::with_capacity(64, endless);
        let e = parse_imu(&mut counted).unwrap_err();
        assert!(e.contains("line 2: longer than"), "{e}");
    }

    #[test]
    fn a_written_bundle_reads_back_and_a_new_one_appears_whole_or_not_at_all() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("b");
        // Dropped before its manifest (a failure mid-way): nothing is left.
        let mut w = BundleWriter::create_new(&dir, (0, 1023)).unwrap();
        w.add_take(0, 1023, (10, 20), "jpg", b"x").unwrap();
        drop(w);
        assert_eq!(std::fs::read_dir(root.path()).unwrap().count(), 0);
        let mut w = BundleWriter::create_new(&dir, (0, 1023)).unwrap();
        w.add_take(0, 1023, (10, 20), "jpg", b"x").unwrap();
        w.add_take(0, 1023, (30, 40), "jpg", b"y").unwrap();
        w.add_take(1, 0, (50, 60), "jpg", b"z").unwrap();
        assert!(!dir.exists());
        let imu = [
            ImuSample {
                t: 5,
                sensor: Sensor::Gyro,
                v: [0.5, -1.25, 3.0],
            },
            ImuSample {
                t: 5,
                sensor: Sensor::Accel,
                v: [0.0, 9.8, 0.0],
            },
        ];
        w.finish(&imu).unwrap();
        let names: Vec<_> = std::fs::read_dir(root.path()).unwrap().flatten().collect();
        assert_eq!(names.len(), 1);
        let b = Bundle::open(&dir).unwrap();
        assert_eq!(b.planes(), 2);
        assert_eq!(b.lens_positions(), vec![1023, 0]);
        assert_eq!(b.manifest.takes[1].image, "plane00_take1.jpg");
        assert_eq!(b.imu, imu.to_vec());
        assert!(dir.join("plane01_take0.jpg").exists());
    }

    proptest::proptest! {
        #[test]
        fn manifest_parser_never_panics(
            plane in proptest::prop_oneof![0usize..4, proptest::num::usize::ANY],
            lens in proptest::num::i32::ANY,
            start in proptest::num::i64::ANY,
            end in proptest::num::i64::ANY,
            image in "[a-z./]{0,12}",
        ) {
            let text = format!(
                "format = 1\nlens_min = 0\nlens_max = 1023\n[[takes]]\nplane = {plane}\nlens = {lens}\n\
                 image = {image:?}\nexposure_start_ns = {start}\nexposure_end_ns = {end}\n"
            );
            let _ = parse_manifest(&text);
        }

        #[test]
        fn imu_parser_never_panics(s in "t_ns,sensor,x,y,z\n([-0-9]{0,20},(gyro|accel|x),[-0-9.eEnaif]{0,8},[0-9.]{0,4},[0-9.]{0,4}\n){0,5}") {
            if let Ok(v) = parse_imu(s.as_bytes()) {
                proptest::prop_assert!(v.windows(2).all(|w| w[0].t <= w[1].t));
            }
        }
    }
}
