//! Benchmarks of the θL-combination study.

use criterion::{criterion_group, criterion_main, Criterion};
use gonio_processing::study::combinations::combinations;

fn enumerate(c: &mut Criterion) {
    let theta_l = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];
    c.bench_function("combinations_6", |b| b.iter(|| combinations(&theta_l)));
}

criterion_group!(benches, enumerate);
criterion_main!(benches);
