//! RGL-EPFL `.bsdf` materials: the reader refuses hostile files with a clear error, the
//! evaluation equals RGL's reference evaluator (powitacq) on synthetic files this test
//! generates, and a scene renders them.
//!
//! The reference values (`tests/fixtures/rgl/`) were computed by the reference evaluator
//! on the files [`synthetic`] writes; `tests/fixtures/rgl/README.md` gives the commands.
//! Real RGL files are tested when `GONIO_RGL_DIR` names a directory of them.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use gonio_mock_hw::render::{self, Shot};
use gonio_mock_hw::scene::rgl::{local_directions, Kind, RglBsdf, RglMaterial};
use gonio_mock_hw::scene::Scene;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

const SMALL: &str = include_str!("../scene_small.toml");
const FIXTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/rgl");

/// A tensor field: name, shape and little-endian bytes.
struct Field {
    name: &'static str,
    dtype: u8,
    shape: Vec<u64>,
    bytes: Vec<u8>,
}

fn floats(name: &'static str, shape: &[usize], values: &[f32]) -> Field {
    assert_eq!(shape.iter().product::<usize>(), values.len(), "{name}");
    Field {
        name,
        dtype: 10,
        shape: shape.iter().map(|&d| d as u64).collect(),
        bytes: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
    }
}

fn bytes(name: &'static str, values: &[u8]) -> Field {
    Field {
        name,
        dtype: 1,
        shape: vec![values.len() as u64],
        bytes: values.to_vec(),
    }
}

/// A tensor file (`tensor_file`, version 1.0): the field headers, then the data of each
/// field at an 8-byte aligned offset.
fn tensor_file(fields: &[Field]) -> Vec<u8> {
    let header_len: usize = 18
        + fields
            .iter()
            .map(|f| 2 + f.name.len() + 2 + 1 + 8 + 8 * f.shape.len())
            .sum::<usize>();
    let mut offset = header_len.next_multiple_of(8);
    let mut out = b"tensor_file\0".to_vec();
    out.extend([1, 0]);
    out.extend((fields.len() as u32).to_le_bytes());
    for f in fields {
        out.extend((f.name.len() as u16).to_le_bytes());
        out.extend(f.name.as_bytes());
        out.extend((f.shape.len() as u16).to_le_bytes());
        out.push(f.dtype);
        out.extend((offset as u64).to_le_bytes());
        for d in &f.shape {
            out.extend(d.to_le_bytes());
        }
        offset = (offset + f.bytes.len()).next_multiple_of(8);
    }
    for f in fields {
        out.resize(out.len().next_multiple_of(8), 0);
        out.extend(&f.bytes);
    }
    out
}

/// The synthetic files the fixture was computed on: (name, seed, spectral, φi slices).
const SYNTHETIC: [(&str, u64, bool, usize); 5] = [
    ("rgb_a", 11, false, 1),
    ("rgb_b", 12, false, 1),
    ("rgb_c", 13, false, 2),
    ("spectral_a", 21, true, 1),
    ("spectral_b", 22, true, 2),
];

/// Direction pairs per synthetic file in the fixture.
const PAIRS_PER_FILE: usize = 2048;

/// A random isotropic material in the powitacq format: grid sizes, θi nodes and
/// wavelengths drawn from `seed`; a Gaussian NDF in θ of random width over a floor,
/// positive σ, a VNDF peaked at a random point, channel values with some nodes below 0
/// (clipped by RGB evaluation, kept by spectral), each value times random noise. With
/// `magnitudes`, the same file with each channel value replaced by its magnitude.
fn synthetic(seed: u64, spectral: bool, phi_n: usize, magnitudes: bool) -> Vec<u8> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let noise = |rng: &mut Pcg64Mcg| rng.random_range(0.8..1.2);
    let theta_n = rng.random_range(3..=6);
    let theta_i: Vec<f32> = (0..theta_n)
        .map(|k| (1.45 * k as f64 / (theta_n - 1) as f64) as f32)
        .collect();
    let phi_i: Vec<f32> = match phi_n {
        1 => vec![0.0],
        _ => vec![-1.0, 1.5],
    };
    let grid = |rng: &mut Pcg64Mcg| (rng.random_range(6..=18), rng.random_range(6..=18));
    let (ndf_x, ndf_y) = grid(&mut rng);
    let alpha = rng.random_range(0.15..0.6);
    let ndf: Vec<f32> = (0..ndf_y * ndf_x)
        .map(|k| {
            let u = (k % ndf_x) as f64 / (ndf_x - 1) as f64;
            let theta = u * u * PI / 2.0;
            (((-(theta / alpha).powi(2)).exp() + 0.01) * noise(&mut rng)) as f32
        })
        .collect();
    let (sigma_x, sigma_y) = grid(&mut rng);
    let sigma: Vec<f32> = (0..sigma_y * sigma_x)
        .map(|k| {
            let u = (k % sigma_x) as f64 / (sigma_x - 1) as f64;
            ((1.0 - 0.6 * u * u) * noise(&mut rng)) as f32
        })
        .collect();
    let slices = phi_n * theta_n;
    let (vndf_x, vndf_y) = grid(&mut rng);
    let (peak_x, peak_y) = (rng.random_range(0.0..0.5), rng.random_range(0.2..0.8));
    let vndf: Vec<f32> = (0..slices * vndf_y * vndf_x)
        .map(|k| {
            let x = (k % vndf_x) as f64 / (vndf_x - 1) as f64 - peak_x;
            let y = (k / vndf_x % vndf_y) as f64 / (vndf_y - 1) as f64 - peak_y;
            (((-(x * x + y * y) / 0.08).exp() + 0.05) * noise(&mut rng)) as f32
        })
        .collect();
    let n = rng.random_range(6..=16);
    let luminance: Vec<f32> = (0..slices * n * n)
        .map(|_| rng.random_range(0.1..1.0))
        .collect();
    let wavelengths: Vec<f32> = if spectral {
        let count = rng.random_range(5..=9);
        (0..count)
            .map(|k| (360.0 + 640.0 * k as f64 / (count - 1) as f64) as f32)
            .collect()
    } else {
        Vec::new()
    };
    let channels = if spectral { wavelengths.len() } else { 3 };
    let values: Vec<f32> = (0..slices * channels * n * n)
        .map(|_| {
            let v: f32 = if rng.random_range(0.0..1.0) < 0.05 {
                rng.random_range(-0.3..-0.05)
            } else {
                rng.random_range(0.05..1.0)
            };
            if magnitudes {
                v.abs()
            } else {
                v
            }
        })
        .collect();
    let mut fields = vec![
        bytes("description", b"synthetic test material"),
        bytes("jacobian", &[1]),
        floats("theta_i", &[theta_n], &theta_i),
        floats("phi_i", &[phi_n], &phi_i),
        floats("ndf", &[ndf_y, ndf_x], &ndf),
        floats("sigma", &[sigma_y, sigma_x], &sigma),
        floats("vndf", &[phi_n, theta_n, vndf_y, vndf_x], &vndf),
        floats("luminance", &[phi_n, theta_n, n, n], &luminance),
    ];
    if spectral {
        fields.push(floats("wavelengths", &[channels], &wavelengths));
        fields.push(floats(
            "spectra",
            &[phi_n, theta_n, channels, n, n],
            &values,
        ));
    } else {
        fields.push(floats("rgb", &[phi_n, theta_n, 3, n, n], &values));
    }
    tensor_file(&fields)
}

/// Direction pairs of one file: half drawn uniformly over the hemisphere, half about
/// the mirror direction (a facet normal up to 40° from the surface normal, at least
/// 0.5°: exactly at the mirror the reference's float32 half vector has no azimuth),
/// both at least 0.6° above the surface; as float32.
fn direction_pairs(seed: u64, count: usize) -> Vec<[f32; 6]> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed ^ 0xd1_4ec7);
    let unit = |rng: &mut Pcg64Mcg, max_theta: f64| {
        let z = rng.random_range(max_theta.cos()..1.0);
        let phi = rng.random_range(-PI..PI);
        let s = (1.0 - z * z).sqrt();
        [s * phi.cos(), s * phi.sin(), z]
    };
    let mut out = Vec::with_capacity(count);
    while out.len() < count {
        let wi = unit(&mut rng, 89.4f64.to_radians());
        let wo = if out.len() % 2 == 0 {
            unit(&mut rng, 89.4f64.to_radians())
        } else {
            let theta_m = rng.random_range(0.5f64.to_radians()..40f64.to_radians());
            let phi_m = rng.random_range(-PI..PI);
            let m = [
                theta_m.sin() * phi_m.cos(),
                theta_m.sin() * phi_m.sin(),
                theta_m.cos(),
            ];
            let d = 2.0 * (wi[0] * m[0] + wi[1] * m[1] + wi[2] * m[2]);
            [d * m[0] - wi[0], d * m[1] - wi[1], d * m[2] - wi[2]]
        };
        if wo[2] < 0.6f64.to_radians().sin() {
            continue;
        }
        let pair = [wi[0], wi[1], wi[2], wo[0], wo[1], wo[2]].map(|v| v as f32);
        out.push(pair);
    }
    out
}

/// FNV-1a, 64 bits: the fixture names each synthetic file by it.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Writes the synthetic files and their direction pairs to `GONIO_RGL_FIXTURE_OUT`, for
/// the reference evaluator (tests/fixtures/rgl/README.md).
#[test]
#[ignore = "writes the reference evaluator's inputs; run with GONIO_RGL_FIXTURE_OUT"]
fn write_fixture_inputs() {
    let out = PathBuf::from(std::env::var_os("GONIO_RGL_FIXTURE_OUT").expect("set it"));
    std::fs::create_dir_all(&out).unwrap();
    for (name, seed, spectral, phi_n) in SYNTHETIC {
        let file = synthetic(seed, spectral, phi_n, false);
        std::fs::write(out.join(format!("{name}.bsdf")), &file).unwrap();
        let lines: String = direction_pairs(seed, PAIRS_PER_FILE)
            .iter()
            .map(|p| {
                let text: Vec<String> = p.iter().map(|v| v.to_string()).collect();
                text.join(",") + "\n"
            })
            .collect();
        std::fs::write(out.join(format!("{name}.directions")), lines).unwrap();
        println!("{name} {:016x}", fnv1a(&file));
    }
}

/// The fixture of one synthetic file: direction pairs and the reference's values.
fn fixture_rows(name: &str) -> Vec<(Vec<f64>, Vec<f64>)> {
    let path = format!("{FIXTURES}/{name}.csv");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    text.lines()
        .skip(1)
        .map(|line| {
            let v: Vec<f64> = line.split(',').map(|s| s.parse().unwrap()).collect();
            (v[..6].to_vec(), v[6..].to_vec())
        })
        .collect()
}

/// The worst difference of `ours` from the reference `theirs` over one pair, relative
/// to `scale` (per value; a reference 0 on a 0 scale must be met by 0).
fn relative(ours: &[f64], theirs: &[f64], scale: &[f64]) -> f64 {
    ours.iter()
        .zip(theirs)
        .zip(scale)
        .map(
            |((a, b), s)| {
                if a == b {
                    0.0
                } else {
                    (a - b).abs() / s.abs()
                }
            },
        )
        .fold(0.0, f64::max)
}

/// Each value within 1e-4 of the reference's, relative to the value itself; where
/// nodes of both signs cancel in the interpolation (the value small beside its terms),
/// relative to the magnitude of the terms, |values| interpolated alike (the same file
/// with every channel value made positive): float32, the reference's arithmetic, is
/// not more precise there, and where nothing cancels the two scales are one.
#[test]
fn evaluation_equals_the_reference_evaluator_on_synthetic_files() {
    let manifest = std::fs::read_to_string(format!("{FIXTURES}/manifest.csv")).unwrap();
    let (mut pairs, mut within_of_value) = (0, 0);
    let (mut worst, mut worst_of_value) = (0.0f64, 0.0f64);
    for (name, seed, spectral, phi_n) in SYNTHETIC {
        let file = synthetic(seed, spectral, phi_n, false);
        let listed = manifest
            .lines()
            .find_map(|l| l.strip_prefix(&format!("{name},")))
            .unwrap_or_else(|| panic!("{name} is not in manifest.csv"));
        assert_eq!(
            listed,
            format!("{:016x}", fnv1a(&file)),
            "{name}: the generator no longer writes the file the reference evaluated"
        );
        let bsdf = RglBsdf::from_bytes(&file).unwrap();
        assert_eq!(matches!(bsdf.kind(), Kind::Spectral { .. }), spectral);
        let terms = RglBsdf::from_bytes(&synthetic(seed, spectral, phi_n, true)).unwrap();
        let rows = fixture_rows(name);
        assert_eq!(rows.len(), PAIRS_PER_FILE, "{name}");
        let mut zeros = 0;
        for (dirs, reference) in &rows {
            let (wi, wo) = ([dirs[0], dirs[1], dirs[2]], [dirs[3], dirs[4], dirs[5]]);
            let ours = bsdf.eval(wi, wo);
            assert_eq!(ours.len(), reference.len(), "{name}");
            let magnitude = terms.eval(wi, wo);
            let r = relative(&ours, reference, &magnitude);
            assert!(
                r <= 1e-4,
                "{name} at {dirs:?}: {ours:?} against the reference {reference:?} ({r:e})"
            );
            worst = worst.max(r);
            let value_relative = relative(&ours, reference, reference);
            worst_of_value = worst_of_value.max(value_relative);
            within_of_value += usize::from(value_relative <= 1e-4);
            zeros += reference.iter().filter(|v| **v == 0.0).count();
        }
        // RGB clips negative values at 0; spectral files keep them.
        assert_eq!(zeros > 0, !spectral, "{name}: {zeros} clipped values");
        pairs += rows.len();
    }
    assert!(pairs >= 10_000);
    println!(
        "{pairs} direction pairs: worst difference {worst:.2e} relative to the terms' \
         magnitude; relative to the value itself {within_of_value} pairs within 1e-4, worst \
         {worst_of_value:.2e}"
    );
}

fn small_scene(sample: &str) -> Result<Scene, String> {
    Scene::from_toml_str(&format!("{SMALL}\n[sample]\n{sample}\n")).map_err(|e| e.to_string())
}

fn with_file(bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("material.bsdf");
    std::fs::write(&path, bytes).unwrap();
    (dir, path)
}

fn scene_error(bytes: &[u8]) -> String {
    let (_dir, path) = with_file(bytes);
    match small_scene(&format!(
        "model = \"rgl\"\nbsdf = {:?}",
        path.display().to_string()
    )) {
        Ok(_) => panic!("the file is accepted"),
        Err(error) => error,
    }
}

#[test]
fn hostile_and_unsupported_files_are_refused_with_one_line_naming_the_problem() {
    let good = synthetic(11, false, 1, false);
    let anisotropic = {
        // Four φi slices: every table grown to match.
        let mut rng = Pcg64Mcg::seed_from_u64(5);
        let mut random =
            |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(0.1..1.0)).collect() };
        tensor_file(&[
            bytes("description", b"x"),
            bytes("jacobian", &[1]),
            floats("theta_i", &[2], &[0.0, 1.0]),
            floats("phi_i", &[4], &[-3.0, -1.0, 1.0, 3.0]),
            floats("ndf", &[2, 2], &random(4)),
            floats("sigma", &[2, 2], &random(4)),
            floats("vndf", &[4, 2, 2, 2], &random(32)),
            floats("luminance", &[4, 2, 2, 2], &random(32)),
            floats("rgb", &[4, 2, 3, 2, 2], &random(96)),
        ])
    };
    let mut huge_extent = good.clone();
    // The first field's first extent (after its 11-byte name, rank, type and offset).
    let at = 18 + 2 + 11 + 2 + 1 + 8;
    huge_extent[at..at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
    let mut bad_version = good.clone();
    bad_version[12] = 2;
    let zero_sigma = tensor_file(&[
        bytes("description", b"x"),
        bytes("jacobian", &[1]),
        floats("theta_i", &[1], &[0.0]),
        floats("phi_i", &[1], &[0.0]),
        floats("ndf", &[2, 2], &[1.0; 4]),
        floats("sigma", &[2, 2], &[1.0, 0.0, 1.0, 1.0]),
        floats("vndf", &[1, 1, 2, 2], &[1.0; 4]),
        floats("luminance", &[1, 1, 2, 2], &[1.0; 4]),
        floats("rgb", &[1, 1, 3, 2, 2], &[1.0; 12]),
    ]);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "anisotropic",
            anisotropic,
            "anisotropic material (4 φi slices)",
        ),
        ("empty", Vec::new(), "not a tensor file"),
        (
            "truncated",
            good[..good.len() / 2].to_vec(),
            "runs past the end of the file",
        ),
        ("header cut", good[..40].to_vec(), "truncated"),
        ("huge extent", huge_extent, "runs past the end of the file"),
        ("version", bad_version, "tensor file version 2.0"),
        (
            "zero σ",
            zero_sigma,
            "field `sigma` holds a non-positive value 0",
        ),
    ];
    for (what, bytes, expected) in cases {
        let error = scene_error(&bytes);
        assert!(error.contains(expected), "{what}: {error}");
        assert!(error.contains("material.bsdf"), "{what}: {error}");
        assert!(!error.contains('\n'), "{what}: {error}");
    }
    let error = small_scene("model = \"rgl\"\nbsdf = \"/dev/zero\"")
        .err()
        .unwrap();
    assert!(error.contains("not a regular file"), "{error}");
}

/// Damaged files (random bytes changed, random lengths cut, float values replaced by
/// extremes) never panic: each is refused with one line, or evaluates to finite β at
/// every geometry, grazing ones included.
#[test]
fn damaged_files_are_refused_or_evaluate_finitely() {
    let scene = small_scene("model = \"lambertian\"\nkd = [1.0, 1.0, 1.0]").unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let originals = [
        synthetic(11, false, 1, false),
        synthetic(22, true, 2, false),
    ];
    let (mut refused, mut accepted) = (0, 0);
    for round in 0..600 {
        let mut bytes = originals[round % 2].clone();
        match round % 3 {
            0 => {
                for _ in 0..rng.random_range(1..8) {
                    let at = rng.random_range(0..bytes.len());
                    bytes[at] = rng.random();
                }
            }
            1 => bytes.truncate(rng.random_range(0..bytes.len())),
            _ => {
                let extremes = [f32::MAX, f32::MIN_POSITIVE, 1e-45, -1.0, 0.0, f32::NAN];
                for _ in 0..rng.random_range(1..4) {
                    let at = 4 * rng.random_range(8..bytes.len() / 4);
                    let v = extremes[rng.random_range(0..extremes.len())];
                    bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
                }
            }
        }
        match RglBsdf::from_bytes(&bytes) {
            Err(error) => {
                assert!(!error.is_empty() && !error.contains('\n'), "{error}");
                refused += 1;
            }
            Ok(bsdf) => {
                let material = RglMaterial::new(bsdf, scene.camera_domain()).unwrap();
                for _ in 0..50 {
                    let cos_i: f64 = rng.random_range(0.0..1.0);
                    let cos_r: f64 = rng.random_range(0.0..1.0);
                    let l_dot_v: f64 = rng.random_range(-1.0..1.0);
                    let beta = material.beta(cos_i, cos_r, l_dot_v);
                    let spectrum = material.beta_spectrum(cos_i, cos_r, l_dot_v);
                    assert!(
                        beta.iter().chain(&spectrum).all(|b| b.is_finite()),
                        "round {round}"
                    );
                }
                accepted += 1;
            }
        }
    }
    assert!(
        refused > 100 && accepted > 100,
        "{refused} refused, {accepted} accepted"
    );
}

/// Linear sRGB of a spectral radiance factor on the 390–730 nm bands: the CIE 1931
/// observer (processing's table) under an equal-energy light, each channel scaled so
/// that a perfect white is 1.
fn srgb(spectrum: &[f64]) -> [f64; 3] {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../processing/data/cie1931_2deg_cmf_390_730_10nm.csv"
    );
    let cmf: Vec<Vec<f64>> = std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').skip(1).map(|v| v.parse().unwrap()).collect())
        .collect();
    let m = [
        [3.2406, -1.5372, -0.4986],
        [-0.9689, 1.8758, 0.0415],
        [0.0557, -0.2040, 1.0570],
    ];
    std::array::from_fn(|k| {
        let w: Vec<f64> = cmf
            .iter()
            .map(|x| (0..3).map(|j| m[k][j] * x[j]).sum())
            .collect();
        w.iter().zip(spectrum).map(|(w, s)| w * s).sum::<f64>() / w.iter().sum::<f64>()
    })
}

/// β of a prepared file at a surface point is π f_r = π·(f_r cos θo)/cos θo of the
/// evaluation at the point's local directions, in camera RGB as the scene's camera and
/// light see it: a spectral file's bands are its wavelengths interpolated, an RGB
/// file's spectrum has the file's linear sRGB, and camera RGB is that of the spectrum.
#[test]
fn prepared_materials_give_the_evaluation_as_radiance_factor() {
    let scene = small_scene("model = \"lambertian\"\nkd = [1.0, 1.0, 1.0]").unwrap();
    let domain = scene.camera_domain();
    let mut rng = Pcg64Mcg::seed_from_u64(99);
    for (name, seed, spectral, phi_n) in SYNTHETIC {
        let bsdf = RglBsdf::from_bytes(&synthetic(seed, spectral, phi_n, false)).unwrap();
        let material = RglMaterial::new(bsdf.clone(), domain).unwrap();
        for _ in 0..500 {
            let cos_i: f64 = rng.random_range(0.02..1.0);
            let cos_r: f64 = rng.random_range(0.02..1.0);
            let (si, sr) = ((1.0 - cos_i * cos_i).sqrt(), (1.0 - cos_r * cos_r).sqrt());
            let l_dot_v = cos_i * cos_r + si * sr * rng.random_range(-1.0..1.0);
            let (wi, wo) = local_directions(cos_i, cos_r, l_dot_v);
            let dot: f64 = (0..3).map(|k| wi[k] * wo[k]).sum();
            assert!((wi[2] - cos_i).abs() < 1e-12 && (wo[2] - cos_r).abs() < 1e-12);
            assert!((dot - l_dot_v).abs() < 1e-9, "{dot} {l_dot_v}");
            let value = bsdf.eval(wi, wo);
            let spectrum = material.beta_spectrum(cos_i, cos_r, l_dot_v);
            let beta = material.beta(cos_i, cos_r, l_dot_v);
            let from_spectrum = domain.rgb(&spectrum);
            for c in 0..3 {
                let scale = beta[c].abs().max(1e-9);
                assert!((from_spectrum[c] - beta[c]).abs() <= 1e-9 * scale, "{name}");
                assert!(beta[c].is_finite());
            }
            if let Kind::Spectral { wavelengths_nm } = bsdf.kind() {
                // Band 560 nm against the file's wavelengths, linearly.
                let k = wavelengths_nm.partition_point(|w| *w <= 560.0) - 1;
                let t = (560.0 - wavelengths_nm[k]) / (wavelengths_nm[k + 1] - wavelengths_nm[k]);
                let expected = PI / cos_r * ((1.0 - t) * value[k] + t * value[k + 1]);
                let band = ((560.0 - 390.0) / 10.0) as usize;
                assert!(
                    (spectrum[band] - expected).abs() <= 1e-9 * expected.abs().max(1e-9),
                    "{name}: {} against {expected}",
                    spectrum[band]
                );
            } else {
                let rgb = srgb(&spectrum);
                let top = value.iter().fold(1e-12f64, |a, b| a.max(PI / cos_r * b));
                for c in 0..3 {
                    let expected = PI / cos_r * value[c];
                    assert!(
                        (rgb[c] - expected).abs() <= 1e-9 * top,
                        "{name}: {rgb:?} {value:?}"
                    );
                }
            }
        }
    }
}

/// The cosines n·l, n·v, l·v of the surface point the pixel at sensor offsets (`x_mm`
/// right, `y_mm` down) sees on the scene's cylinder (axis z through the origin, camera
/// at (camera distance, 0, 0) looking along −x, light in the z = 0 plane at θL), traced
/// in 3D here independently of the renderer.
fn pixel_cosines(scene: &Scene, theta_l_deg: f64, x_mm: f64, y_mm: f64) -> [f64; 3] {
    let s = scene.setup();
    let (dc, r, f) = (
        s.camera_distance_mm,
        s.cylinder_radius_mm,
        s.focal_length_mm,
    );
    let d = [-f, x_mm, -y_mm];
    // |(dc, 0) + t (d0, d1)|² = r², the nearer root.
    let a = d[0] * d[0] + d[1] * d[1];
    let b = 2.0 * dc * d[0];
    let c = dc * dc - r * r;
    let t = (-b - (b * b - 4.0 * a * c).sqrt()) / (2.0 * a);
    let p = [dc + t * d[0], t * d[1], t * d[2]];
    let n = [p[0] / r, p[1] / r, 0.0];
    let tl = theta_l_deg.to_radians();
    let light = [
        s.light_distance_mm * tl.cos(),
        s.light_distance_mm * tl.sin(),
        0.0,
    ];
    let l: Vec<f64> = (0..3).map(|k| light[k] - p[k]).collect();
    let v: Vec<f64> = (0..3).map(|k| [dc, 0.0, 0.0][k] - p[k]).collect();
    let dot = |a: &[f64], b: &[f64]| -> f64 { (0..3).map(|k| a[k] * b[k]).sum() };
    let (ll, vv) = (dot(&l, &l).sqrt(), dot(&v, &v).sqrt());
    [dot(&n, &l) / ll, dot(&n, &v) / vv, dot(&l, &v) / (ll * vv)]
}

/// A scene whose sample is a `.bsdf` file renders it at each pixel's 3D geometry: a
/// sample pixel over the white pixel at the mirrored row (same light, same gain) is
/// β(n·l, n·v, l·v)/(ρ_white·W) up to the rounding of the counts, at every pixel of the
/// sample strip where both are well exposed.
#[test]
fn a_scene_renders_a_bsdf_sample_at_each_pixels_geometry() {
    let file = synthetic(12, false, 1, false);
    let (dir, path) = with_file(&file);
    std::fs::write(
        dir.path().join("scene.toml"),
        format!("{SMALL}\n[sample]\nmodel = \"rgl\"\nbsdf = \"material.bsdf\"\n"),
    )
    .unwrap();
    let scene = Scene::load(&dir.path().join("scene.toml")).unwrap();
    assert_eq!(scene.sample().model_name(), "rgl");
    assert_eq!(scene.truth_json()["bsdf"], path.display().to_string());
    let material =
        RglMaterial::new(RglBsdf::from_bytes(&file).unwrap(), scene.camera_domain()).unwrap();
    let theta_l = -30.0;
    let frame = render::render(
        &scene,
        &Shot {
            theta_l_deg: theta_l,
            shutter_s: 0.002,
            iso: 100,
            frame_index: 0,
        },
    );
    let s = scene.setup();
    let white = scene
        .camera_domain()
        .white_rgb()
        .map(|w| w * scene.white_reflectance());
    let pitch = s.pixel_pitch_um / 1000.0;
    let mut checked = 0;
    for row in s.sample_rows[0]..=s.sample_rows[1] {
        let mirror = (2.0 * s.cy() - f64::from(row)) as u32;
        for u in 0..frame.width() {
            let (sample, reference) = (frame.pixel(u, row), frame.pixel(u, mirror));
            let x_mm = (f64::from(u) - s.cx()) * pitch;
            let y_mm = (f64::from(row) - s.cy()) * pitch;
            let [cos_i, cos_r, l_dot_v] = pixel_cosines(&scene, theta_l, x_mm, y_mm);
            let beta = material.beta(cos_i, cos_r, l_dot_v);
            for c in 0..3 {
                let (a, b) = (f64::from(sample[c]), f64::from(reference[c]));
                if !(200.0..60_000.0).contains(&a) || !(200.0..60_000.0).contains(&b) {
                    continue;
                }
                let expected = beta[c] / white[c];
                let tolerance = expected * (0.6 / a + 0.6 / b);
                assert!(
                    (a / b - expected).abs() <= tolerance,
                    "pixel ({u}, {row}) channel {c}: {a}/{b} against β ratio {expected}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 1000, "{checked} values checked");
}

/// Real RGL files, when `GONIO_RGL_DIR` names a directory of them: every isotropic file
/// loads and gives finite, non-negative β in camera RGB; an anisotropic one (`aniso_`)
/// is refused as such; where `<name>.reference.csv` lies beside a file (the reference
/// evaluator's output, tests/fixtures/rgl/README.md), the evaluation agrees with it as
/// [`check_reference`] states.
#[test]
fn real_rgl_files_when_gonio_rgl_dir_is_set() {
    let Some(dir) = std::env::var_os("GONIO_RGL_DIR") else {
        println!("skipped: set GONIO_RGL_DIR to a directory of RGL-EPFL .bsdf files");
        return;
    };
    let scene = small_scene("model = \"lambertian\"\nkd = [1.0, 1.0, 1.0]").unwrap();
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "bsdf"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no .bsdf file in {dir:?}");
    for path in files {
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        let bsdf = match RglBsdf::read(&path) {
            Ok(bsdf) => bsdf,
            Err(e) => {
                assert!(
                    name.starts_with("aniso") && e.to_string().contains("anisotropic"),
                    "{name}: {e}"
                );
                println!("{name}: refused: {e}");
                continue;
            }
        };
        check_reference(&path, &bsdf);
        let material = RglMaterial::new(bsdf, scene.camera_domain()).unwrap();
        let mut peak = [0.0f64; 3];
        for ti in (0..90).step_by(5) {
            for tr in -89..90 {
                let (ti, tr) = (f64::from(ti).to_radians(), f64::from(tr).to_radians());
                let l_dot_v = ti.cos() * tr.cos() - ti.sin() * tr.sin();
                let beta = material.beta(ti.cos(), tr.cos(), l_dot_v);
                assert!(
                    beta.iter().all(|b| b.is_finite() && *b >= 0.0),
                    "{name}: {beta:?}"
                );
                for (p, b) in peak.iter_mut().zip(beta) {
                    *p = p.max(b);
                }
            }
        }
        println!("{name}: peak in-plane β {peak:.1?}");
    }
}

/// The tensor file `bytes` with every value of its `rgb` or `spectra` field replaced by
/// its magnitude.
fn with_magnitudes(bytes: &[u8]) -> Vec<u8> {
    let mut out = bytes.to_vec();
    let read = |at: usize, n: usize| -> u64 {
        let mut b = [0u8; 8];
        b[..n].copy_from_slice(&bytes[at..at + n]);
        u64::from_le_bytes(b)
    };
    let mut at = 18;
    for _ in 0..read(14, 4) {
        let name_len = read(at, 2) as usize;
        let name = &bytes[at + 2..at + 2 + name_len];
        at += 2 + name_len;
        let rank = read(at, 2) as usize;
        let offset = read(at + 3, 8) as usize;
        let count: u64 = (0..rank).map(|k| read(at + 11 + 8 * k, 8)).product();
        at += 11 + 8 * rank;
        if name == b"rgb" || name == b"spectra" {
            for k in 0..count as usize {
                out[offset + 4 * k + 3] &= 0x7f;
            }
        }
    }
    out
}

/// Compares with `<name>.reference.csv` beside the file, when there is one: within 1e-3
/// of the terms' magnitude (as the synthetic files are compared, there within 1e-4) for
/// every pair with both directions within 80° of the normal; the figures are printed.
/// Real tables vary up to a thousandfold across one cell, most near grazing angles,
/// where the reference's float32 rounding of the warped point (one unit in the last
/// place) moves a value by up to a few 1e-3 of itself; pairs beyond 80° are counted and
/// their worst difference printed.
fn check_reference(path: &Path, bsdf: &RglBsdf) {
    let reference = path.with_extension("reference.csv");
    let Ok(text) = std::fs::read_to_string(&reference) else {
        return;
    };
    let terms = RglBsdf::from_bytes(&with_magnitudes(&std::fs::read(path).unwrap())).unwrap();
    let grazing = 80f64.to_radians().cos();
    let (mut plain, mut steep, mut grazing_worst) = (Vec::new(), 0.0f64, 0.0f64);
    let mut grazing_pairs = 0;
    for line in text.lines() {
        let v: Vec<f64> = line.split(',').map(|s| s.parse().unwrap()).collect();
        let (wi, wo) = ([v[0], v[1], v[2]], [v[3], v[4], v[5]]);
        let ours = bsdf.eval(wi, wo);
        let theirs = &v[6..];
        plain.push(relative(&ours, theirs, theirs));
        let r = relative(&ours, theirs, &terms.eval(wi, wo));
        if wi[2] < grazing || wo[2] < grazing {
            grazing_pairs += 1;
            grazing_worst = grazing_worst.max(r);
        } else {
            steep = steep.max(r);
        }
    }
    plain.sort_by(f64::total_cmp);
    let n = plain.len();
    let within = plain.partition_point(|r| *r <= 1e-4);
    println!(
        "{}: {within} of {n} pairs within 1e-4 of the value (median {:.1e}, worst {:.1e}); \
         of the terms' magnitude, worst {steep:.1e} within 80° of the normal, \
         {grazing_worst:.1e} over the {grazing_pairs} pairs beyond",
        reference.display(),
        plain[n / 2],
        plain[n - 1]
    );
    assert!(steep <= 1e-3, "{}: {steep:e}", reference.display());
}
