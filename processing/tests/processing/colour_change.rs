//! The model-free test of the lobe's chromaticity across θL (`fit::colour_change`) over a
//! randomized family of synthetic scans (seeded draws, six θL): its false-alarm rate on
//! specular lobes of one colour over any diffuse colour, with relative noise from none to
//! 2 %, is at most its stated level (1 %, with binomial slack) and no such scan reports a
//! colour change; lobes whose specular colour changes with θd by a visible amount are
//! (at least twice the smallest change reported) are reported in at least 95 % of scans.

use gonio_processing::brdf::{Model, Params};
use gonio_processing::color::CameraModel;
use gonio_processing::fit::colour_change::{lobe_colour_change, LEVEL, MIN_UV_CHANGE};

use crate::common;
use crate::synthetic;
use common::Rng;
use synthetic::{scan, Noise};

const THETA_L: [f64; 6] = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];

/// Scans of each family.
const SCANS: usize = 150;

/// A drawn material: diffuse of any colour, a specular colour, roughness and noise.
fn draw(rng: &mut Rng) -> (Params, f64) {
    let kd = std::array::from_fn(|_| 1.0 + 30.0 * rng.uniform());
    let grey = 5.0 + 60.0 * rng.uniform();
    let tint: [f64; 3] = std::array::from_fn(|_| 0.6 + 0.8 * rng.uniform());
    let m = 0.03 + 0.3 * rng.uniform();
    // One in four scans without noise, the others up to 2 % (about 4× the emulator's
    // relative noise on a lobe).
    let noise = if rng.uniform() < 0.25 {
        0.0
    } else {
        0.02 * rng.uniform()
    };
    (Params::shared(kd, tint.map(|t| grey * t), m), noise)
}

#[test]
fn one_specular_colour_is_rarely_significant_and_never_reported() {
    let camera = CameraModel::builtin();
    let mut rng = Rng(0x5eed_c01c);
    let (mut significant, mut reported, mut tested, mut judged) = (0, 0, 0, 0);
    for _ in 0..SCANS {
        let (p, noise) = draw(&mut rng);
        let noise = Noise {
            relative: noise,
            absolute: 0.0,
        };
        let samples = scan(
            Model::CookTorrance,
            &p,
            &p.ks,
            &THETA_L,
            0.5,
            noise,
            &mut rng,
        );
        let Some(test) = lobe_colour_change(&samples, &camera) else {
            continue;
        };
        judged += 1;
        reported += usize::from(test.changes);
        // Without noise every difference is significant (p = 0): the size decides alone.
        if noise.relative > 0.0 {
            tested += 1;
            significant += usize::from(test.p_value < LEVEL);
        }
    }
    eprintln!(
        "one specular colour: {significant} of {tested} with noise significant, \
         {reported} of {judged} reported"
    );
    assert!(judged >= SCANS * 9 / 10, "{judged}");
    // Binomial(≤ 150, 0.01): 6 or more has probability below 0.1 %.
    assert!(significant <= 5, "{significant} of {tested}");
    assert_eq!(reported, 0);
}

#[test]
fn a_specular_colour_that_changes_with_angle_is_reported() {
    let camera = CameraModel::builtin();
    let mut rng = Rng(0xc01c_5eed);
    let (mut reported, mut tested) = (0, 0);
    for _ in 0..SCANS {
        let (p, noise) = draw(&mut rng);
        let noise = Noise {
            relative: noise,
            absolute: 0.0,
        };
        // At 90° the specular takes another hue: its channels' shares rotated.
        let ks_90 = [p.ks[1], p.ks[2], p.ks[0]];
        // The specular's u′v′ at the extreme θL (F linear in 1 − cos γ, γ = |θL|): only
        // a change at least twice the smallest reported is asked to be seen.
        let at = |gamma: f64| {
            let w = 1.0 - gamma.to_radians().cos();
            camera.uv_prime(std::array::from_fn(|c| p.ks[c] * (1.0 - w) + ks_90[c] * w))
        };
        let (a, b) = (at(20.0).unwrap(), at(45.0).unwrap());
        if ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt() < 2.0 * MIN_UV_CHANGE {
            continue;
        }
        let samples = scan(
            Model::CookTorranceFresnel,
            &p,
            &ks_90,
            &THETA_L,
            0.5,
            noise,
            &mut rng,
        );
        let Some(test) = lobe_colour_change(&samples, &camera) else {
            continue;
        };
        tested += 1;
        reported += usize::from(test.changes);
        if !test.changes {
            eprintln!("not reported: noise {:.4} {test:?}", noise.relative);
        }
    }
    eprintln!("changing specular colour: {reported} of {tested} reported");
    assert!(tested >= SCANS / 3, "{tested}");
    assert!(reported * 100 >= tested * 95, "{reported} of {tested}");
}
