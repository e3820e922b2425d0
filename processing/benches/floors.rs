//! What this machine allows, for the floor column of README's cost table
//! (scripts/bench_table.py): its memory bandwidth, and the cost of one point of a fit's
//! loss for each model.
//!
//! - **Bandwidth**, bytes per second on every core: reading (a sum over a 512 MiB
//!   buffer) and copying (bytes read plus bytes written), the best of 5 passes. A merge
//!   or a decode can go no faster than reading its input and writing its output at it.
//! - **One point of the loss** (eq. 10), seconds: the model at a prepared point and its
//!   distance to the measured value, as the fits evaluate it (`fit::PreparedLoss`: a
//!   shared roughness and one specular colour through the columns' loop, the fastest),
//!   on one core over 100,000 points, the median of 21 passes. A fit can go no faster
//!   than its loss evaluations × its points × this, shared over every core.
//!
//!     cargo bench -p gonio-processing --bench floors
//!
//! The last line is the result as JSON (`{"bench": "floors", ...}`), which
//! scripts/bench.sh keeps.

use std::hint::black_box;
use std::time::Instant;

use gonio_processing::brdf::{Model, Params};
use gonio_processing::fit::PreparedLoss;
use gonio_processing::samples::Sample;
use rayon::prelude::*;

/// Size of the buffer the bandwidth is measured on: far beyond any cache.
const BUFFER_BYTES: usize = 512 << 20;
/// Points of the loss pass.
const POINTS: usize = 100_000;

/// Seconds of the fastest of `passes` runs of `f`.
fn fastest(passes: usize, mut f: impl FnMut()) -> f64 {
    (0..passes)
        .map(|_| {
            let started = Instant::now();
            f();
            started.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// Read and copy bandwidth on every core, bytes per second.
fn bandwidth() -> (f64, f64) {
    let words = BUFFER_BYTES / 8;
    let source: Vec<u64> = (0..words as u64).collect();
    let mut target = vec![0u64; words];
    let chunk = 1 << 16;
    let read_s = fastest(5, || {
        let sum: u64 = source
            .par_chunks(chunk)
            .map(|c| c.iter().fold(0u64, |a, &b| a.wrapping_add(b)))
            .reduce(|| 0, u64::wrapping_add);
        black_box(sum);
    });
    let copy_s = fastest(5, || {
        target
            .par_chunks_mut(chunk)
            .zip(source.par_chunks(chunk))
            .for_each(|(t, s)| t.copy_from_slice(s));
        black_box(&target);
    });
    let bytes = BUFFER_BYTES as f64;
    (bytes / read_s, 2.0 * bytes / copy_s)
}

/// Median seconds of one point of `model`'s loss, on one core, evaluated as the fits
/// evaluate it ([`PreparedLoss`]).
fn point_seconds(model: Model) -> f64 {
    let params = Params::shared([8.0, 6.0, 3.0], [4.0, 3.5, 2.0], 0.12);
    // A specular colour that changes with angle for the model that fits one.
    let ks_90 = match model {
        Model::CookTorranceFresnel => [5.0, 3.0, 2.5],
        _ => params.ks,
    };
    let samples: Vec<Sample> = (0..POINTS)
        .map(|k| {
            let phi = -60.0 + 120.0 * k as f64 / POINTS as f64;
            let (theta_i, theta_r) = (-30.0 - phi, phi);
            let beta = model
                .basis(theta_i, theta_r)
                .evaluate_fresnel(&params, &ks_90);
            Sample::in_plane(-30.0, theta_i, theta_r, beta)
        })
        .collect();
    let loss = PreparedLoss::new(&samples, model).expect("enough points");
    let mut passes: Vec<f64> = (0..21)
        .map(|_| {
            let started = Instant::now();
            black_box(black_box(&loss).at(&params, &ks_90));
            started.elapsed().as_secs_f64()
        })
        .collect();
    passes.sort_by(f64::total_cmp);
    passes[passes.len() / 2] / POINTS as f64
}

fn main() {
    let (read, copy) = bandwidth();
    let point_s: serde_json::Map<String, serde_json::Value> =
        [Model::CookTorrance, Model::Ward, Model::CookTorranceFresnel]
            .into_iter()
            .map(|model| (model.to_string(), point_seconds(model).into()))
            .collect();
    println!(
        "read bandwidth {:.1} GB/s, copy {:.1} GB/s on {} cores",
        read / 1e9,
        copy / 1e9,
        rayon::current_num_threads()
    );
    for (model, seconds) in &point_s {
        let ns = seconds.as_f64().unwrap_or(f64::NAN) * 1e9;
        println!("one point of the {model} loss: {ns:.2} ns");
    }
    println!(
        "{}",
        serde_json::json!({
            "bench": "floors",
            "cores": rayon::current_num_threads(),
            "read_bytes_per_s": read,
            "copy_bytes_per_s": copy,
            "point_s": point_s,
        })
    );
}
