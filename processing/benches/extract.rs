//! Turning a 6-θL scan (full-size 16-bit TIFF brackets) into samples.
//!
//! `GONIO_BENCH_SCAN=DIR cargo bench -p gonio-processing --bench extract` times the scan
//! in DIR (e.g. made by `gonio simulate --scene gold --out DIR`); without it a synthetic
//! Lambertian scan (6 θL × 4 exposures, 3872×2592) is written to a temporary directory.
//! Timed with each sample's uncertainty (the default) and without.

use std::path::{Path, PathBuf};

use criterion::{criterion_group, criterion_main, Criterion};
mod common;

use common::{d200_setup, THETA_L};
use gonio_processing::capture::{self, Response, Sidecar};
use gonio_processing::extract::{self, ExtractOptions};

const BRACKET: [f64; 4] = [0.5, 0.125, 1.0 / 30.0, 0.01];

fn write_synthetic_scan(dir: &Path) {
    let setup = d200_setup();
    let json = serde_json::to_string(&setup).expect("setup JSON");
    std::fs::write(dir.join("setup.json"), json).expect("write setup.json");
    let (w, h) = (setup.image_width as usize, setup.image_height as usize);
    for theta_l in THETA_L {
        let sub = dir.join(format!("theta_l_{theta_l:.1}"));
        std::fs::create_dir_all(&sub).expect("create scan directory");
        let cosines: Vec<f64> = (0..w)
            .map(|u| {
                setup
                    .angles_at_column(u as f64, theta_l)
                    .map_or(0.0, |a| a.theta_i.to_radians().cos().max(0.0))
            })
            .collect();
        for (n, shutter_s) in BRACKET.into_iter().enumerate() {
            let mut counts = Vec::with_capacity(w * h * 3);
            for y in 0..h {
                let reflectance = if y < 1296 { 0.3 } else { 1.0 };
                for cos in &cosines {
                    for gain in [1.0, 0.9, 0.4] {
                        let signal = (4.0 * reflectance * gain * cos * shutter_s).min(1.0);
                        counts.push((signal * 4095.0).round() as u16);
                    }
                }
            }
            let sidecar = Sidecar {
                shutter_s,
                iso: Some(100.0),
                theta_l,
                camera: "bench".into(),
                time: "2026-11-23T15:00:00Z".into(),
                black_level: Some(0.0),
                white_level: Some(4095.0),
                response: Response::Linear,
                significant_bits: None,
                aperture: None,
                width: None,
                height: None,
            };
            let path = sub.join(format!("exp_{n:02}.tiff"));
            capture::write_tiff_capture(&path, w as u32, h as u32, &counts, &sidecar)
                .expect("write capture");
        }
    }
}

/// The captures of a scan folder: every capture file one level down.
fn walk_captures(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .flat_map(|theta| {
            std::fs::read_dir(theta.path())
                .into_iter()
                .flatten()
                .flatten()
        })
        .map(|entry| entry.path())
        .filter(|path| capture::is_capture_path(path))
        .collect()
}

fn extract_six_theta_scan(c: &mut Criterion) {
    let temporary;
    let dir: PathBuf = match std::env::var_os("GONIO_BENCH_SCAN") {
        Some(dir) => PathBuf::from(dir),
        None => {
            temporary = tempfile::tempdir().expect("temporary directory");
            write_synthetic_scan(temporary.path());
            temporary.path().to_path_buf()
        }
    };
    let out = dir.join("bench-samples.csv");
    // What extraction must read at least, for the floor column of README's cost table.
    let file_bytes: u64 = walk_captures(&dir)
        .iter()
        .map(|p| std::fs::metadata(p).map_or(0, |m| m.len()))
        .sum();
    println!(
        "{}",
        serde_json::json!({ "bench": "extract_input", "file_bytes": file_bytes })
    );
    let mut group = c.benchmark_group("extract");
    group.sample_size(10);
    // With each sample's uncertainty (the default: its noise, and its change under each
    // of the setup's sources, the geometric ones from the moved setups' geometry at
    // knots), and without.
    for (name, uncertainty) in [
        ("six_theta_l_scan_to_csv", true),
        ("six_theta_l_scan_to_csv/no-uncertainty", false),
    ] {
        let options = ExtractOptions {
            uncertainty,
            ..ExtractOptions::default()
        };
        group.bench_function(name, |b| {
            b.iter(|| {
                let extraction = extract::extract_scan(&dir, &options).expect("extraction");
                gonio_processing::samples::write_csv(&out, &extraction.samples)
                    .expect("write samples");
            })
        });
    }
    group.finish();
}

criterion_group!(benches, extract_six_theta_scan);
criterion_main!(benches);
