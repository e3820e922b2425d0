//! The processing steps of a scan (docs/ARCHITECTURE.md, "Daemon"): once a θL's
//! bracket is captured, its samples (and the live fits over every θL so far) and its
//! HDR map; once every bracket is, all samples gathered and the model fits. Outputs
//! are written atomically; each step returns the result record of its journal row.
//! Frames may be decoded ahead of their HDR step ([`Prefetched`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;
use gonio_files::input::{read_input, MAX_SMALL_FILE_BYTES};
use gonio_processing::brdf::Model;
use gonio_processing::capture::{is_capture_path, sidecar_path, CaptureError, Frame};
use gonio_processing::color::CameraModel;
use gonio_processing::extract::{extract_scan, ExtractOptions};
use gonio_processing::fit::{fit, fit_auto, FitOptions, FitResult, AUTO_CANDIDATES};
use gonio_processing::hdr::{merge, MergeOptions};
use gonio_processing::metrics::err_p;
use gonio_processing::samples::{read_csv, write_csv, Sample};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

use super::files::{write_atomic, write_atomic_with};
use super::fit_cache::fingerprint;
pub use super::fit_cache::Budgets;
use super::plan::{
    theta_dir_name, theta_fits_path, theta_map_path, theta_map_record_path, theta_samples_path,
    ScanPlan, Step, AUTO_FIT, FIT_MODELS,
};
use super::store::now_rfc3339;

/// Most frames decoded ahead of their HDR step (a full-size 16-bit frame is 60 MB).
const PREFETCH_FRAMES: usize = 8;

/// Frames decoded ahead of their HDR step, while the rest of their bracket is
/// captured, so that the merge after a bracket's last capture decodes one frame
/// rather than all. A cache only: the HDR step decodes whatever is not here, and
/// journals when the frames it took were decoded (`decoded_ahead`: the lane's work
/// for the step, which the time left measures with the step's own).
#[derive(Debug, Default)]
pub struct Prefetched {
    frames: Vec<(Frame, DecodeRun)>,
    /// Frames that did not decode: the HDR step reports why.
    failed: Vec<PathBuf>,
}

/// When a frame decoded ahead began and ended decoding (RFC 3339).
type DecodeRun = [String; 2];

impl Prefetched {
    /// Forgets the frames not in `wanted` (paths of frames awaiting their HDR step),
    /// then decodes the first one not decoded yet, if there is room; returns whether
    /// it decoded one.
    pub fn advance(&mut self, wanted: &[PathBuf]) -> bool {
        self.frames.retain(|(f, _)| wanted.contains(&f.path));
        self.failed.retain(|p| wanted.contains(p));
        if self.frames.len() >= PREFETCH_FRAMES {
            return false;
        }
        let Some(path) = wanted
            .iter()
            .find(|p| !self.failed.contains(p) && self.position(p).is_none())
        else {
            return false;
        };
        let started = now_rfc3339();
        match Frame::read(path) {
            Ok(frame) => self.frames.push((frame, [started, now_rfc3339()])),
            Err(_) => self.failed.push(path.clone()),
        }
        true
    }

    /// Where the frame decoded from `path` is held, if it is.
    fn position(&self, path: &Path) -> Option<usize> {
        self.frames.iter().position(|(f, _)| f.path == path)
    }

    /// The frames at `paths`, in order: those decoded ahead taken from here, the
    /// others decoded now, in parallel; and when those taken from here were decoded.
    fn take(&mut self, paths: &[PathBuf]) -> Result<(Vec<Frame>, Vec<DecodeRun>), CaptureError> {
        let missing: Vec<PathBuf> = paths
            .iter()
            .filter(|p| self.position(p).is_none())
            .cloned()
            .collect();
        let mut decoded = Frame::read_all(&missing)?.into_iter();
        let mut runs = Vec::new();
        let frames = paths
            .iter()
            .filter_map(|p| match self.position(p) {
                Some(i) => {
                    let (frame, run) = self.frames.swap_remove(i);
                    runs.push(run);
                    Some(frame)
                }
                None => decoded.next(),
            })
            .collect();
        Ok((frames, runs))
    }
}

/// Runs one processing step of the scan `plan` in scan directory `dir` (extraction
/// with setup.json's white reflectance); the HDR step takes the frames decoded ahead
/// from `prefetched`, a fit step its budget from `budgets` when the same fit has one.
/// Returns the step's result record.
pub fn run(
    step: &Step,
    dir: &Path,
    plan: &ScanPlan,
    prefetched: &mut Prefetched,
    budgets: &Budgets,
) -> anyhow::Result<Value> {
    match step {
        Step::Samples { theta_l } => samples(dir, plan, *theta_l),
        Step::Hdr { theta_l } => hdr(dir, *theta_l, prefetched),
        Step::Extract => gather(dir, plan),
        Step::Fit { model } => fit_model(dir, plan, model, budgets),
        Step::Home | Step::Move { .. } | Step::Meter { .. } | Step::Capture { .. } => {
            anyhow::bail!("{} is not a processing step", step.describe())
        }
    }
}

/// The samples of θL's captures alone.
fn extract_theta(dir: &Path, theta_l: f64) -> anyhow::Result<Vec<Sample>> {
    let options = ExtractOptions {
        theta_l: Some(theta_l),
        ..ExtractOptions::default()
    };
    Ok(extract_scan(dir, &options)?.samples)
}

/// The samples of one θL as its samples step wrote them.
fn read_theta(dir: &Path, theta_l: f64) -> anyhow::Result<Vec<Sample>> {
    let rel = theta_samples_path(theta_l);
    read_csv(&dir.join(&rel)).with_context(|| rel)
}

/// A θL's samples and live fits; the result says how many samples, and the seconds
/// their extraction took (`extract_s`, the rest of the step being the live fits).
fn samples(dir: &Path, plan: &ScanPlan, theta_l: f64) -> anyhow::Result<Value> {
    let began = std::time::Instant::now();
    let samples = extract_theta(dir, theta_l)?;
    let extract_s = began.elapsed().as_secs_f64();
    let rel = theta_samples_path(theta_l);
    write_atomic_with(&dir.join(&rel), |tmp| write_csv(tmp, &samples))
        .with_context(|| rel.clone())?;
    let live = live_fits(dir, plan, theta_l, &samples)?;
    Ok(json!({ "path": rel, "samples": samples.len(), "extract_s": extract_s, "live": live }))
}

/// The robust fits over every θL measured so far, `newest` the samples of the last
/// one, `theta_l`. Beside each fit's parameters and in-sample ΔErr_p (eq. 11):
/// `held_out_err_p`, the ΔErr_p at the newest θL of the fit made before it was
/// measured, and `change_p`, how far the fitted β moved at every point with it (the
/// ΔErr_p between the two fits' predictions); both fall as more θL stop paying.
///
/// The samples are fitted in ascending θL, the order of `samples.csv`, and the fits
/// are saved ([`SavedFits`]): the next θL's fits before are these, and the last θL's
/// are the scan's fits once `samples.csv` is gathered. Fits that cannot be read are
/// made again.
fn live_fits(
    dir: &Path,
    plan: &ScanPlan,
    theta_l: f64,
    newest: &[Sample],
) -> anyhow::Result<Value> {
    let position = plan
        .theta_l
        .iter()
        .position(|t| *t == theta_l)
        .with_context(|| format!("θL {theta_l}° is not in the scan's plan"))?;
    let mut by_theta = Vec::new();
    for &t in &plan.theta_l[..position] {
        by_theta.push((t, read_theta(dir, t)?));
    }
    by_theta.sort_by(|a, b| a.0.total_cmp(&b.0));
    let earlier: Vec<Sample> = by_theta
        .iter()
        .flat_map(|(_, s)| s.iter().copied())
        .collect();
    let at = by_theta.partition_point(|(t, _)| t.total_cmp(&theta_l).is_lt());
    by_theta.insert(at, (theta_l, newest.to_vec()));
    let all: Vec<Sample> = by_theta.into_iter().flat_map(|(_, s)| s).collect();
    let saved = position
        .checked_sub(1)
        .and_then(|previous| SavedFits::read(dir, plan.theta_l[previous]));
    let mut fits = serde_json::Map::new();
    let mut to_save = SavedFits {
        samples: fingerprint(&all),
        fits: BTreeMap::new(),
    };
    let earlier_fingerprint = fingerprint(&earlier);
    // The models are fitted side by side: each fit runs on one core.
    let made: Vec<(Value, Option<FitResult>)> = FIT_MODELS
        .par_iter()
        .map(|(model, _)| {
            let options = FitOptions::new(model.parse::<Model>()?);
            Ok(match fit(&all, &options) {
                Ok(now) => {
                    let before = match saved
                        .as_ref()
                        .and_then(|s| s.of(model, &earlier_fingerprint))
                    {
                        Some(before) => Some(before.clone()),
                        None if earlier.is_empty() => None,
                        None => fit(&earlier, &options).ok(),
                    };
                    (live_entry(&now, before.as_ref(), newest, &all), Some(now))
                }
                Err(err) => (json!({ "error": err.to_string() }), None),
            })
        })
        .collect::<anyhow::Result<_>>()?;
    for ((model, _), (entry, now)) in FIT_MODELS.iter().zip(made) {
        if let Some(now) = now {
            to_save.fits.insert((*model).to_owned(), now);
        }
        fits.insert((*model).to_owned(), entry);
    }
    let rel = theta_fits_path(theta_l);
    write_atomic(&dir.join(&rel), &serde_json::to_vec(&to_save)?).with_context(|| rel)?;
    Ok(json!({
        "theta_l": plan.theta_l[..=position],
        "samples": all.len(),
        "fits": fits,
    }))
}

/// The live fits a θL's samples step saved (`samples/theta_l_<θL>.fits.json`): the fit
/// of each model to every θL up to it, and the [`fingerprint`] of the samples fitted.
#[derive(Serialize, Deserialize)]
struct SavedFits {
    samples: String,
    fits: BTreeMap<String, FitResult>,
}

impl SavedFits {
    /// The fits θL's samples step saved; none when they cannot be read.
    fn read(dir: &Path, theta_l: f64) -> Option<SavedFits> {
        let bytes = read_input(&dir.join(theta_fits_path(theta_l)), MAX_SMALL_FILE_BYTES).ok()?;
        serde_json::from_slice(&bytes).ok()
    }

    /// The saved fit of `model`, if it was made on exactly the samples of `fingerprint`.
    fn of(&self, model: &str, fingerprint: &str) -> Option<&FitResult> {
        (self.samples == fingerprint)
            .then(|| self.fits.get(model))
            .flatten()
    }
}

fn predictions(fit: &FitResult, samples: &[Sample]) -> Vec<[f64; 3]> {
    samples.iter().map(|s| fit.predict_sample(s)).collect()
}

fn live_entry(
    now: &FitResult,
    before: Option<&FitResult>,
    newest: &[Sample],
    all: &[Sample],
) -> Value {
    let measured: Vec<[f64; 3]> = newest.iter().map(|s| s.rgb).collect();
    let held_out = before.and_then(|b| err_p(&measured, &predictions(b, newest)).ok());
    let change = before.and_then(|b| err_p(&predictions(now, all), &predictions(b, all)).ok());
    json!({
        "kd": now.kd,
        "ks": now.ks,
        "m": now.m,
        "loss": now.loss,
        "err_p": now.err_p,
        "held_out_err_p": held_out,
        "change_p": change,
    })
}

/// θL's HDR map. A map made before a restart is kept as it is when its record says it
/// was made from exactly these frames and its bytes are intact ([`MapRecord`]); else it
/// is merged again.
fn hdr(dir: &Path, theta_l: f64, prefetched: &mut Prefetched) -> anyhow::Result<Value> {
    let frame_dir = dir.join(theta_dir_name(theta_l));
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&frame_dir)
        .with_context(|| frame_dir.display().to_string())?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| is_capture_path(p))
        .collect();
    paths.sort();
    let rel = theta_map_path(theta_l);
    let map = dir.join(&rel);
    let record_path = dir.join(theta_map_record_path(theta_l));
    let inputs = map_inputs(&paths);
    if MapRecord::read(&record_path).is_some_and(|r| r.holds(&inputs, &map)) {
        tracing::info!("{rel}: kept, made from the same frames before the restart");
        return Ok(json!({ "path": rel, "frames": paths.len(), "kept": true }));
    }
    let (frames, decoded_ahead) = prefetched.take(&paths)?;
    let image = merge(&frames, &MergeOptions::default())?;
    write_atomic_with(&map, |tmp| image.write_exr(tmp))?;
    let record = MapRecord::of(inputs, &map).with_context(|| rel.clone())?;
    write_atomic(&record_path, &serde_json::to_vec(&record)?)
        .with_context(|| theta_map_record_path(theta_l))?;
    Ok(json!({ "path": rel, "frames": frames.len(), "decoded_ahead": decoded_ahead }))
}

/// The files an HDR map is made from (each capture and its sidecar, those that exist):
/// name, length and modification time (nanoseconds since the epoch). Captures are
/// written atomically and never rewritten, so equal stamps mean the same frames.
type MapInputs = Vec<(String, u64, u64)>;

/// The [`MapInputs`] of the captures at `paths`.
fn map_inputs(paths: &[PathBuf]) -> MapInputs {
    paths
        .iter()
        .flat_map(|capture| [capture.clone(), sidecar_path(capture)])
        .filter_map(|path| {
            let meta = std::fs::metadata(&path).ok()?;
            let modified = meta
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
            let name = path.file_name()?.to_string_lossy().into_owned();
            Some((name, meta.len(), modified))
        })
        .collect()
}

/// The record written beside an HDR map once it is in place
/// (`hdr/theta_l_<θL>.exr.json`): the stamps of the frames it was made from, its length
/// and its CRC-32.
#[derive(Debug, PartialEq, Serialize, Deserialize)]
struct MapRecord {
    inputs: MapInputs,
    bytes: u64,
    crc32: u32,
}

impl MapRecord {
    /// The record of the map at `map`, made from `inputs`.
    fn of(inputs: MapInputs, map: &Path) -> std::io::Result<MapRecord> {
        let (bytes, crc32) = checksum(map)?;
        Ok(MapRecord {
            inputs,
            bytes,
            crc32,
        })
    }

    /// The record at `path`; none when it cannot be read.
    fn read(path: &Path) -> Option<MapRecord> {
        let bytes = read_input(path, MAX_SMALL_FILE_BYTES).ok()?;
        serde_json::from_slice(&bytes).ok()
    }

    /// Whether the map at `map` is the one recorded, made from `inputs`.
    fn holds(&self, inputs: &MapInputs, map: &Path) -> bool {
        self.inputs == *inputs
            && std::fs::metadata(map).is_ok_and(|m| m.is_file() && m.len() == self.bytes)
            && checksum(map).is_ok_and(|sum| sum == (self.bytes, self.crc32))
    }
}

/// The length and CRC-32 of the file at `path`.
fn checksum(path: &Path) -> std::io::Result<(u64, u32)> {
    use std::io::Read;
    let mut file = std::fs::File::open(path)?;
    let mut hasher = crc32fast::Hasher::new();
    let mut buffer = vec![0u8; 1 << 20];
    let mut bytes = 0u64;
    loop {
        let n = file.read(&mut buffer)?;
        if n == 0 {
            return Ok((bytes, hasher.finalize()));
        }
        hasher.update(&buffer[..n]);
        bytes += n as u64;
    }
}

/// `samples.csv`: the samples of every θL in ascending θL, as `gonio extract` orders
/// them; a θL without its samples file (a scan planned before samples steps existed)
/// is extracted here.
fn gather(dir: &Path, plan: &ScanPlan) -> anyhow::Result<Value> {
    let mut theta_ls = plan.theta_l.clone();
    theta_ls.sort_by(f64::total_cmp);
    let mut samples = Vec::new();
    for theta_l in theta_ls {
        if dir.join(theta_samples_path(theta_l)).is_file() {
            samples.extend(read_theta(dir, theta_l)?);
        } else {
            samples.extend(extract_theta(dir, theta_l)?);
        }
    }
    if samples.is_empty() {
        // Say why, as `gonio extract` does: extracting the whole scan counts what it
        // dropped.
        let extraction = extract_scan(dir, &ExtractOptions::default())?;
        anyhow::bail!("{}", extraction.dropped.explain_empty());
    }
    write_atomic_with(&dir.join("samples.csv"), |tmp| write_csv(tmp, &samples))?;
    Ok(json!({ "path": "samples.csv", "samples": samples.len() }))
}

/// Fits `model` to `samples.csv`; the last θL's live fit is taken as it is when it
/// was made on exactly those samples (as it is once every θL is processed). The
/// [`AUTO_FIT`] chooses among the models by the θL each fit did not see. The budget is
/// taken from `budgets` when the same fit of the same samples has one (the auto fit
/// choosing a model as its own fit has it, whichever of the two is made first).
fn fit_model(dir: &Path, plan: &ScanPlan, model: &str, budgets: &Budgets) -> anyhow::Result<Value> {
    let name = FIT_MODELS
        .iter()
        .chain([&AUTO_FIT])
        .find(|(m, _)| *m == model)
        .map(|(_, name)| *name)
        .with_context(|| format!("unknown model {model:?}"))?;
    let samples = read_csv(&dir.join("samples.csv"))?;
    // The last θL's live fit of a model, made on exactly these samples.
    let live = |model: &str| {
        plan.theta_l
            .last()
            .and_then(|&last| SavedFits::read(dir, last))
            .and_then(|saved| saved.of(model, &fingerprint(&samples)).cloned())
    };
    let result = if model == AUTO_FIT.0 {
        let chosen = fit_auto(&samples, &AUTO_CANDIDATES, &CameraModel::builtin())?;
        // A choice of one of the scan's per-model fits (shared roughness) is that fit,
        // with the choice recorded: the choice's own refit from the samples it judged
        // reaches the same minimum to its precision, and the scan's files then agree
        // and share one budget.
        match live(chosen.model.name()) {
            Some(own) if own.roughness == chosen.roughness => FitResult {
                selection: chosen.selection,
                table: chosen.table,
                seconds: chosen.seconds,
                ..own
            },
            _ => chosen,
        }
    } else {
        match live(model) {
            Some(result) => result,
            None => fit(&samples, &FitOptions::new(model.parse::<Model>()?))?,
        }
    };
    let result = FitResult {
        budget: budgets.of(&samples, &result)?,
        ..result
    };
    write_atomic(&dir.join(name), &serde_json::to_vec_pretty(&result)?)
        .with_context(|| name.to_owned())?;
    let mut record = json!({ "path": name, "loss": result.loss });
    if let Some(selection) = &result.selection {
        record["model"] = json!(result.model);
        record["roughness"] = json!(result.roughness);
        record["colour_shift"] = json!(selection.colour_shift);
        record["reason"] = json!(selection.reason);
        record["table"] = json!(result.table.is_some());
    }
    Ok(record)
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_processing::capture::{write_tiff_capture, Response, Sidecar};

    fn write_frames(dir: &Path, count: usize) -> Vec<PathBuf> {
        (0..count)
            .map(|n| {
                let path = dir.join(format!("exp_{n:02}.tiff"));
                let sidecar = Sidecar {
                    shutter_s: 0.1 / (n + 1) as f64,
                    iso: Some(100.0),
                    theta_l: -20.0,
                    camera: "test".into(),
                    time: "2026-01-01T00:00:00Z".into(),
                    black_level: Some(0.0),
                    white_level: Some(4095.0),
                    response: Response::Linear,
                    significant_bits: Some(12),
                    aperture: None,
                    width: None,
                    height: None,
                };
                let counts: Vec<u16> = (0..4 * 3 * 3).map(|v| (v * 100 + n) as u16).collect();
                write_tiff_capture(&path, 4, 3, &counts, &sidecar).unwrap();
                path
            })
            .collect()
    }

    #[test]
    fn frames_decoded_ahead_are_the_frames_the_hdr_step_would_decode() {
        let dir = tempfile::tempdir().unwrap();
        let paths = write_frames(dir.path(), 3);
        let fresh = Frame::read_all(&paths).unwrap();
        let mut prefetched = Prefetched::default();
        // Two of three frames captured so far: both are decoded ahead, one at a time.
        assert!(prefetched.advance(&paths[..2]));
        assert!(prefetched.advance(&paths[..2]));
        assert!(!prefetched.advance(&paths[..2]));
        assert_eq!(prefetched.frames.len(), 2);
        let (frames, runs) = prefetched.take(&paths).unwrap();
        assert_eq!(frames, fresh);
        // When each frame taken was decoded, in order.
        assert_eq!(runs.len(), 2);
        assert!(runs.iter().all(|[from, to]| from <= to));
        assert!(prefetched.frames.is_empty());
        // Frames no longer awaited are forgotten; one that does not decode is not
        // tried again, and the HDR step reports it.
        assert!(prefetched.advance(&paths[..1]));
        let broken = dir.path().join("exp_09.tiff");
        std::fs::write(&broken, b"not a TIFF").unwrap();
        assert!(prefetched.advance(std::slice::from_ref(&broken)));
        assert!(prefetched.frames.is_empty());
        assert!(!prefetched.advance(std::slice::from_ref(&broken)));
        assert!(prefetched.take(&[broken]).is_err());
    }

    /// A map merged before a restart (its step not recorded done) is kept when its
    /// frames and its bytes are those recorded, and merged again, to the same bytes,
    /// when the map is damaged or missing, its record is, or a frame changed.
    #[test]
    fn a_map_made_before_a_restart_is_kept_while_its_frames_and_bytes_are_intact() {
        use std::os::unix::fs::MetadataExt;
        let dir = tempfile::tempdir().unwrap();
        let dir = dir.path();
        let frames = dir.join(theta_dir_name(-20.0));
        std::fs::create_dir(&frames).unwrap();
        let paths = write_frames(&frames, 3);
        let map = dir.join(theta_map_path(-20.0));
        let record = dir.join(theta_map_record_path(-20.0));
        let run = || hdr(dir, -20.0, &mut Prefetched::default()).unwrap();
        let kept = |result: &Value| result.get("kept") == Some(&json!(true));
        assert!(!kept(&run()));
        let made = std::fs::read(&map).unwrap();
        let inode = std::fs::metadata(&map).unwrap().ino();
        assert!(kept(&run()));
        assert_eq!(std::fs::metadata(&map).unwrap().ino(), inode);
        assert_eq!(std::fs::read(&map).unwrap(), made);
        // Damaged in place at the same length, cut short, missing, unrecorded.
        let mut damaged = made.clone();
        damaged[made.len() / 2] ^= 0x40;
        let spoil: [&dyn Fn(); 4] = [
            &|| std::fs::write(&map, &damaged).unwrap(),
            &|| std::fs::write(&map, &made[..made.len() - 1]).unwrap(),
            &|| std::fs::remove_file(&map).unwrap(),
            &|| std::fs::remove_file(&record).unwrap(),
        ];
        for (k, spoil) in spoil.iter().enumerate() {
            spoil();
            assert!(!kept(&run()), "case {k}");
            assert_eq!(std::fs::read(&map).unwrap(), made, "case {k}");
            assert!(kept(&run()), "case {k}");
        }
        // A frame taken again (another exposure): merged again, from it.
        let sidecar = sidecar_path(&paths[1]);
        let mut text: Value = serde_json::from_slice(&std::fs::read(&sidecar).unwrap()).unwrap();
        text["shutter_s"] = json!(0.04);
        std::fs::write(&sidecar, serde_json::to_vec(&text).unwrap()).unwrap();
        assert!(!kept(&run()));
        assert_ne!(std::fs::read(&map).unwrap(), made);
    }

    fn theta_samples(theta_l: f64) -> Vec<Sample> {
        (0..40)
            .map(|i| {
                let theta_i = -30.0 + 1.5 * f64::from(i);
                let theta_r = theta_l - theta_i;
                let lobe = 2.0 * (-((theta_i - theta_r) / 12.0).powi(2)).exp();
                Sample::in_plane(
                    theta_l,
                    theta_i,
                    theta_r,
                    [0.3 + lobe, 0.2 + lobe, 0.1 + lobe],
                )
            })
            .collect()
    }

    #[test]
    fn live_fits_are_saved_for_the_next_theta_l_and_become_the_scan_fits() {
        let dir = tempfile::tempdir().unwrap();
        let dir = dir.path();
        std::fs::create_dir(dir.join("samples")).unwrap();
        let plan = ScanPlan {
            sample: "s".into(),
            theta_l: vec![-20.0, -40.0, -30.0],
            shutter_s: Vec::new(),
            auto_bracket: true,
        };
        let mut live = Vec::new();
        for &theta_l in &plan.theta_l {
            let samples = theta_samples(theta_l);
            write_csv(&dir.join(theta_samples_path(theta_l)), &samples).unwrap();
            live.push(live_fits(dir, &plan, theta_l, &samples).unwrap());
        }
        let held_out = &live[2]["fits"]["ward"]["held_out_err_p"];
        assert!(held_out.is_array(), "{held_out}");
        // The fits before the last θL are those the previous step saved: made again
        // without them, they are the same.
        std::fs::remove_file(dir.join(theta_fits_path(-40.0))).unwrap();
        let again = live_fits(dir, &plan, -30.0, &theta_samples(-30.0)).unwrap();
        assert_eq!(again, live[2]);
        // Once samples.csv is gathered, the last θL's fits are the scan's: the same as
        // fitting samples.csv.
        gather(dir, &plan).unwrap();
        let gathered = read_csv(&dir.join("samples.csv")).unwrap();
        let scan_fits = |dir: &Path| -> Vec<FitResult> {
            FIT_MODELS
                .iter()
                .map(|(model, name)| {
                    fit_model(dir, &plan, model, &Budgets::default()).unwrap();
                    serde_json::from_slice(&std::fs::read(dir.join(name)).unwrap()).unwrap()
                })
                .collect()
        };
        let fresh: Vec<FitResult> = FIT_MODELS
            .iter()
            .map(|(model, _)| fit(&gathered, &FitOptions::new(model.parse().unwrap())).unwrap())
            .collect();
        let same = |a: &[FitResult], b: &[FitResult]| {
            a.iter().zip(b).all(|(a, b)| {
                a == &FitResult {
                    seconds: a.seconds,
                    ..b.clone()
                }
            })
        };
        assert!(same(&scan_fits(dir), &fresh));
        // They are taken as they are saved when they are of exactly these samples, and
        // fitted again when not, or when they cannot be read.
        let path = dir.join(theta_fits_path(-30.0));
        let mut saved: SavedFits = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        assert_eq!(saved.samples, fingerprint(&gathered));
        for fit in saved.fits.values_mut() {
            fit.kd = [9.0; 3];
        }
        std::fs::write(&path, serde_json::to_vec(&saved).unwrap()).unwrap();
        assert!(scan_fits(dir).iter().all(|f| f.kd == [9.0; 3]));
        saved.samples = fingerprint(&gathered[1..]);
        std::fs::write(&path, serde_json::to_vec(&saved).unwrap()).unwrap();
        assert!(same(&scan_fits(dir), &fresh));
        std::fs::write(&path, b"{").unwrap();
        assert!(same(&scan_fits(dir), &fresh));
        // The last fit chooses among the models, and says why, in its file and record.
        let record = fit_model(dir, &plan, AUTO_FIT.0, &Budgets::default()).unwrap();
        let auto: FitResult =
            serde_json::from_slice(&std::fs::read(dir.join(AUTO_FIT.1)).unwrap()).unwrap();
        let selection = auto.selection.expect("an auto fit records its choice");
        assert_eq!(selection.candidates.len(), AUTO_CANDIDATES.len());
        let chosen = selection.candidates[selection.chosen].form;
        match chosen.variant() {
            Some(v) => assert_eq!((v.model, auto.table.is_none()), (auto.model, true)),
            None => assert!(auto.table.is_some(), "{chosen:?}"),
        }
        assert_eq!(record["reason"], json!(selection.reason));
    }
}
