//! Render time of one full D200-size frame (3872×2592) per effect set.
//!
//! `cargo bench -p gonio-mock-hw --bench render`

use criterion::{criterion_group, criterion_main, Criterion};
use gonio_mock_hw::render::render_frame;
use gonio_mock_hw::scene::{
    Effects, HotPixels, Misalignment, Response, RetroReflection, Scene, Vignetting,
};

fn with_effects(name: &str, effects: Effects) -> Scene {
    let mut scene = Scene::builtin(name).expect("built-in scene");
    scene.set_effects(effects).expect("valid effects");
    scene
}

fn render(c: &mut Criterion) {
    let gold = Scene::builtin("gold").expect("built-in scene");
    let noise = gold.effects().noise.clone();
    let all = Effects {
        seed: 3,
        noise: noise.clone(),
        vignetting: Some(Vignetting { strength: 1.0 }),
        response: Some(Response { gamma: 2.2 }),
        hot_pixels: Some(HotPixels { count: 500 }),
        retro_reflection: Some(RetroReflection {
            kr: [5.0, 5.0, 5.0],
            width_deg: 5.0,
        }),
        misalignment: None,
    };
    let misaligned = Effects {
        misalignment: Some(Misalignment {
            camera_offset_mm: 3.0,
            camera_yaw_deg: 0.2,
            camera_roll_deg: 0.1,
            cylinder_tilt_deg: 0.5,
            arm_zero_offset_deg: 0.3,
            light_distance_error_mm: 5.0,
            white_reflectance_error: 0.01,
            white_falloff: 0.03,
            camera_distance_error_mm: 2.0,
            arm_angle_errors_deg: vec![0.01; gold.theta_l_deg().len()],
        }),
        ..gold.effects().clone()
    };
    let sets = [
        ("none", with_effects("gold", Effects::default())),
        ("default effects (noise, vignetting)", gold.clone()),
        (
            "noise",
            with_effects(
                "gold",
                Effects {
                    noise,
                    ..Effects::default()
                },
            ),
        ),
        (
            "misaligned (default effects + every misalignment)",
            with_effects("gold", misaligned),
        ),
        (
            "spectral (thin film)",
            with_effects("blue-green", Effects::default()),
        ),
        (
            "all (thin film + every effect)",
            with_effects("blue-green", all),
        ),
    ];
    let mut group = c.benchmark_group("render 3872x2592");
    for (label, scene) in &sets {
        group.bench_function(*label, |b| b.iter(|| render_frame(scene, -30.0, 0.125)));
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(std::time::Duration::from_secs(1))
        .measurement_time(std::time::Duration::from_secs(4));
    targets = render
}
criterion_main!(benches);
