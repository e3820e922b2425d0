//! Merging a bracket of 7 full-size frames (3872×2592 RGB, the paper's camera).
//!
//! `cargo bench -p gonio-processing --bench hdr`; peak memory:
//! `/usr/bin/time -v target/release/deps/hdr-<hash> --bench linear`.

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use gonio_processing::capture::{Frame, Response, Sidecar};
use gonio_processing::hdr::{self, MergeMethod, MergeOptions};

const WIDTH: usize = 3872;
const HEIGHT: usize = 2592;
const BRACKET: [f64; 7] = [
    1.0 / 100.0,
    1.0 / 50.0,
    1.0 / 25.0,
    1.0 / 13.0,
    1.0 / 8.0,
    1.0 / 4.0,
    1.0 / 2.0,
];

/// A frame of a scene spanning four decades of radiance, with a little pseudo-noise.
fn frame(shutter_s: f64, response: Response) -> Frame {
    let (black, white) = (600.0, 60_000.0);
    let mut data = Vec::with_capacity(WIDTH * HEIGHT * 3);
    for y in 0..HEIGHT {
        for x in 0..WIDTH {
            let radiance = 0.05
                * 10f64.powf(4.0 * x as f64 / WIDTH as f64)
                * (1.0 + 0.2 * (y as f64 / HEIGHT as f64));
            for c in 0..3 {
                let jitter = ((x * 31 + y * 17 + c * 7) % 13) as f64 - 6.0;
                let signal = (radiance * [1.0, 0.8, 0.5][c] * shutter_s).min(1.0);
                let count = (black + signal * (white - black) + jitter).clamp(0.0, 65_535.0);
                data.push(count as u16);
            }
        }
    }
    let sidecar = Sidecar {
        shutter_s,
        iso: Some(100.0),
        theta_l: -30.0,
        camera: "bench".into(),
        time: "2026-11-23T15:00:00Z".into(),
        black_level: Some(black),
        white_level: Some(white),
        response,
        significant_bits: None,
        aperture: None,
        width: None,
        height: None,
    };
    Frame::from_counts(
        PathBuf::from("bench.tiff"),
        sidecar,
        WIDTH,
        HEIGHT,
        data,
        65_535.0,
    )
    .expect("valid bench frame")
}

fn merge_bracket(c: &mut Criterion) {
    let linear: Vec<Frame> = BRACKET
        .iter()
        .map(|&t| frame(t, Response::Linear))
        .collect();
    let mut group = c.benchmark_group("hdr_merge_7x3872x2592");
    group.sample_size(10);
    group.bench_function("linear", |b| {
        b.iter(|| hdr::merge(black_box(&linear), &MergeOptions::default()).expect("merge"))
    });
    let options = MergeOptions {
        method: MergeMethod::DebevecMalik,
        ..MergeOptions::default()
    };
    group.bench_function("debevec_malik", |b| {
        b.iter(|| hdr::merge(black_box(&linear), &options).expect("merge"))
    });
    group.finish();
}

criterion_group!(benches, merge_bracket);
criterion_main!(benches);
