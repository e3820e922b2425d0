//! Rendering: radiometry against the white reference, geometry against an independent
//! angle-form computation, determinism, noise statistics and each effect.

use gonio_mock_hw::render::{self, reference, render_frame, Frame16, Shot};
use gonio_mock_hw::scene::material::thin_film_reflectance;
use gonio_mock_hw::scene::Scene;

const SMALL: &str = include_str!("../scene_small.toml");
const THETA_L: f64 = -30.0;
const SHUTTER: f64 = 0.01;

fn scene(extra: &str) -> Scene {
    Scene::from_toml_str(&format!("{SMALL}\n{extra}")).unwrap()
}

/// A Lambertian sample of flat reflectance `rho` (kd = ρ·W in camera RGB).
fn lambertian(rho: f64, effects: &str) -> Scene {
    let w = scene("[sample]\nmodel = \"lambertian\"\nkd = [1.0, 1.0, 1.0]\n")
        .camera_domain()
        .white_rgb();
    scene(&format!(
        "[sample]\nmodel = \"lambertian\"\nkd = [{}, {}, {}]\n{effects}",
        rho * w[0],
        rho * w[1],
        rho * w[2]
    ))
}

/// Mean of the 5 rows centred on `row` in column `u`, per channel.
fn strip_mean(frame: &Frame16, u: u32, row: u32) -> [f64; 3] {
    let mut sum = [0.0; 3];
    for y in row - 2..=row + 2 {
        for (s, v) in sum.iter_mut().zip(frame.pixel(u, y)) {
            *s += f64::from(v) / 5.0;
        }
    }
    sum
}

#[test]
fn lambertian_over_white_is_rho_over_rho_w_in_every_column() {
    let (rho, rho_w) = (0.4, 0.9);
    let scene = lambertian(rho, "");
    let frame = render_frame(&scene, THETA_L, SHUTTER);
    let (sample_row, white_row) = (scene.setup().sample_row(), scene.setup().white_row());
    let mut lit = 0;
    for u in 0..frame.width() {
        let white = strip_mean(&frame, u, white_row);
        let sample = strip_mean(&frame, u, sample_row);
        // Everywhere, up to rounding of the counts.
        for c in 0..3 {
            assert!(
                (sample[c] - rho / rho_w * white[c]).abs() <= 1.0,
                "column {u} channel {c}"
            );
        }
        if white[1] < 1000.0 {
            continue;
        }
        lit += 1;
        for c in 0..3 {
            let ratio = sample[c] / white[c];
            assert!(
                (ratio - rho / rho_w).abs() < 1e-3,
                "column {u} channel {c}: {ratio}"
            );
        }
    }
    assert!(lit > 250, "only {lit} lit columns");
}

/// Signed in-plane angles (degrees) at column `u` for a camera at angle 0 and the light
/// at θL, by angle arithmetic: φ from the hit point, θi = angle(L − P) − φ,
/// θr = φ − angle(C − P).
fn column_angles(scene: &Scene, u: u32, theta_l: f64) -> Option<(f64, f64)> {
    let s = scene.setup();
    let x = (f64::from(u) - s.cx()) * s.pixel_pitch_um / 1000.0;
    let psi = (x / s.focal_length_mm).atan();
    // Law of sines in the triangle axis–camera–hit point.
    let sin_gamma = s.camera_distance_mm * psi.sin() / s.cylinder_radius_mm;
    if sin_gamma.abs() > 1.0 {
        return None;
    }
    let gamma = std::f64::consts::PI - sin_gamma.asin();
    let phi = std::f64::consts::PI - gamma - psi;
    let (px, py) = (
        s.cylinder_radius_mm * phi.cos(),
        s.cylinder_radius_mm * phi.sin(),
    );
    let tl = theta_l.to_radians();
    let (lx, ly) = (
        s.light_distance_mm * tl.cos(),
        s.light_distance_mm * tl.sin(),
    );
    let to_light = (ly - py).atan2(lx - px);
    let to_camera = (-py).atan2(s.camera_distance_mm - px);
    Some((
        (to_light - phi).to_degrees(),
        (phi - to_camera).to_degrees(),
    ))
}

/// Cook–Torrance in angle form (docs/ARCHITECTURE.md, "Quantities and models"), camera-RGB β.
fn cook_torrance(kd: [f64; 3], ks: [f64; 3], m: f64, ti: f64, tr: f64) -> [f64; 3] {
    let (ti, tr) = (ti.to_radians(), tr.to_radians());
    let alpha = (ti - tr) / 2.0;
    let d = (-(alpha.tan() / m).powi(2)).exp() / (m * m * alpha.cos().powi(4));
    let vh = ((ti + tr) / 2.0).cos();
    let g = (2.0 * alpha.cos() * tr.cos() / vh)
        .min(2.0 * alpha.cos() * ti.cos() / vh)
        .min(1.0);
    std::array::from_fn(|c| ks[c] * d * g / (std::f64::consts::PI * ti.cos() * tr.cos()) + kd[c])
}

#[test]
fn cook_torrance_render_matches_angle_form_per_column() {
    let (kd, ks, m) = ([20.0, 15.0, 5.0], [6.0, 4.0, 2.0], 0.3);
    // Strips hugging the optical axis, so the out-of-plane tilt is negligible.
    let text = format!(
        "{SMALL}\n[sample]\nmodel = \"cook-torrance\"\nkd = {kd:?}\nks = {ks:?}\nm = [{m}]\n"
    )
    .replace("sample_rows = [20, 40]", "sample_rows = [55, 57]")
    .replace("white_rows = [79, 99]", "white_rows = [62, 64]");
    let scene = Scene::from_toml_str(&text).unwrap();
    let w = scene.camera_domain().white_rgb();
    let frame = render_frame(&scene, THETA_L, SHUTTER);
    let mut checked = 0;
    let mut peak = (0.0, 0.0, 0.0);
    for u in 0..frame.width() {
        let Some((ti, tr)) = column_angles(&scene, u, THETA_L) else {
            assert_eq!(
                frame.pixel(u, 56),
                [0, 0, 0],
                "column {u} misses the cylinder"
            );
            continue;
        };
        let (s, wh) = (frame.pixel(u, 56), frame.pixel(u, 63));
        if wh[1] < 2000 || ti.abs() > 70.0 || tr.abs() > 70.0 {
            continue;
        }
        let expected = cook_torrance(kd, ks, m, ti, tr);
        for c in 0..3 {
            let beta = f64::from(s[c]) / f64::from(wh[c]) * 0.9 * w[c];
            assert!(
                (beta / expected[c] - 1.0).abs() < 0.01,
                "column {u} (θi {ti:.2}, θr {tr:.2}) channel {c}: {beta} vs {}",
                expected[c]
            );
        }
        if f64::from(s[1]) / f64::from(wh[1]) > peak.0 {
            peak = (f64::from(s[1]) / f64::from(wh[1]), ti, tr);
        }
        checked += 1;
    }
    assert!(checked > 200, "{checked}");
    // The brightest column is the specular one, θi ≈ θr.
    assert!((peak.1 - peak.2).abs() < 1.0, "{peak:?}");
}

#[test]
fn reference_matches_angle_form_models() {
    let (kd, ks) = ([30.0, 20.0, 10.0], [5.0, 4.0, 1.0]);
    for (model, m) in [("cook-torrance", 0.2), ("ward", 0.25)] {
        let scene = scene(&format!(
            "[sample]\nmodel = \"{model}\"\nkd = {kd:?}\nks = {ks:?}\nm = [{m}]\n"
        ));
        let csv = reference::reference_csv(&scene);
        let mut lines = csv.lines();
        let header = lines.next().unwrap();
        assert!(header.starts_with("theta_i,theta_r,390,400,"));
        assert!(header.ends_with(",720,730"));
        let rows: Vec<Vec<f64>> = lines
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect();
        assert_eq!(rows.len(), 33 * 33);
        for row in &rows {
            assert_eq!(row.len(), 37);
            let (ti, tr) = (row[0], row[1]);
            let spectrum: [f64; 35] = std::array::from_fn(|i| row[i + 2]);
            let rgb = scene.camera_domain().rgb(&spectrum);
            let expected = if model == "ward" {
                let alpha = ((ti - tr) / 2.0).to_radians();
                let lobe = (-(alpha.tan() / m).powi(2)).exp()
                    / (4.0
                        * std::f64::consts::PI
                        * m
                        * m
                        * (ti.to_radians().cos() * tr.to_radians().cos()).sqrt());
                std::array::from_fn(|c| kd[c] / std::f64::consts::PI + ks[c] * lobe)
            } else {
                cook_torrance(kd, ks, m, ti, tr)
            };
            for c in 0..3 {
                assert!(
                    (rgb[c] / expected[c] - 1.0).abs() < 1e-5,
                    "{model} θi {ti} θr {tr} channel {c}: {} vs {}",
                    rgb[c],
                    expected[c]
                );
            }
        }
    }
}

const NOISE: &str =
    "[effects]\nseed = 7\n[effects.noise]\nelectrons_per_dn = 4.0\nread_noise_dn = 3.0\n";

#[test]
fn renders_are_deterministic_for_a_seed() {
    let mut noisy = lambertian(0.5, NOISE);
    let a = render_frame(&noisy, THETA_L, SHUTTER);
    assert_eq!(a, render_frame(&noisy, THETA_L, SHUTTER));
    let other_frame = render::render(
        &noisy,
        &Shot {
            theta_l_deg: THETA_L,
            shutter_s: SHUTTER,
            iso: 100,
            frame_index: 1,
        },
    );
    assert_ne!(a, other_frame);
    noisy.set_seed(8);
    assert_ne!(a, render_frame(&noisy, THETA_L, SHUTTER));
    // Without noise the seed changes nothing.
    let mut clean = lambertian(0.5, "");
    let b = render_frame(&clean, THETA_L, SHUTTER);
    clean.set_seed(99);
    assert_eq!(b, render_frame(&clean, THETA_L, SHUTTER));
}

#[test]
fn noise_statistics_match_shot_plus_read_model() {
    let black = 256.0;
    let with_black = |s: &str| {
        let w = lambertian(0.5, s);
        let text = format!(
            "{SMALL}\n[sample]\nmodel = \"lambertian\"\nkd = {:?}\n{s}",
            match w.sample() {
                gonio_mock_hw::scene::Sample::Lambertian { kd } => kd,
                _ => unreachable!(),
            }
        )
        .replace("black_level = 0", "black_level = 256");
        Scene::from_toml_str(&text).unwrap()
    };
    for iso in [100, 400] {
        let shot = Shot {
            theta_l_deg: THETA_L,
            shutter_s: SHUTTER * 100.0 / f64::from(iso),
            iso,
            frame_index: 0,
        };
        let clean = render::render(&with_black(""), &shot);
        let noisy = render::render(&with_black(NOISE), &shot);
        let electrons_per_dn = 4.0 * 100.0 / f64::from(iso);
        let (mut n, mut sum, mut sum_norm) = (0.0, 0.0, 0.0);
        let (mut dark_n, mut dark_sum, mut dark_sq) = (0.0, 0.0, 0.0);
        for (c, v) in clean.data().iter().zip(noisy.data()) {
            let (c, v) = (f64::from(*c), f64::from(*v));
            let signal = c - black;
            if signal > 200.0 {
                let d = v - c;
                n += 1.0;
                sum += d;
                sum_norm += d * d / (signal / electrons_per_dn + 9.0 + 1.0 / 6.0);
            } else if signal == 0.0 {
                dark_n += 1.0;
                dark_sum += v;
                dark_sq += (v - black) * (v - black);
            }
        }
        assert!(n > 20_000.0 && dark_n > 50_000.0);
        let mean_d = sum / n;
        assert!(mean_d.abs() < 0.5, "ISO {iso}: mean offset {mean_d}");
        let var_ratio = sum_norm / n;
        assert!(
            (var_ratio - 1.0).abs() < 0.04,
            "ISO {iso}: variance ratio {var_ratio}"
        );
        let dark_mean = dark_sum / dark_n;
        assert!((dark_mean - black).abs() < 0.05, "dark mean {dark_mean}");
        let dark_var = dark_sq / dark_n;
        assert!(
            (dark_var / (9.0 + 1.0 / 12.0) - 1.0).abs() < 0.03,
            "dark variance {dark_var}"
        );
    }
}

#[test]
fn dark_areas_and_clipping() {
    let scene = lambertian(0.5, "");
    let frame = render_frame(&scene, THETA_L, SHUTTER);
    // Rows between the strips, and columns off the cylinder, are black.
    for u in 0..frame.width() {
        assert_eq!(frame.pixel(u, 60), [0, 0, 0]);
    }
    assert_eq!(frame.pixel(0, 30), [0, 0, 0]);
    let bright = render_frame(&scene, THETA_L, SHUTTER * 1000.0);
    assert_eq!(bright.data().iter().max(), Some(&65535));
    let text = format!("{SMALL}\n[sample]\nmodel = \"lambertian\"\nkd = [50.0, 50.0, 50.0]\n")
        .replace("bit_depth = 16", "bit_depth = 12")
        .replace("white_level = 65535", "white_level = 4000");
    let twelve = render_frame(&Scene::from_toml_str(&text).unwrap(), THETA_L, 1.0);
    assert_eq!(twelve.data().iter().max(), Some(&4000));
}

#[test]
fn vignetting_follows_cos4() {
    let plain = render_frame(&lambertian(0.5, ""), THETA_L, SHUTTER);
    let vignetted = render_frame(
        &lambertian(0.5, "[effects.vignetting]\nstrength = 1.0\n"),
        THETA_L,
        SHUTTER,
    );
    let (f, pitch, cx, cy) = (85.0, 0.03, 199.5, 59.5);
    let mut checked = 0;
    for u in 0..400 {
        for y in [20, 30, 99] {
            let (p, v) = (plain.pixel(u, y), vignetted.pixel(u, y));
            if p[1] < 5000 {
                continue;
            }
            let (x, yy) = ((f64::from(u) - cx) * pitch, (f64::from(y) - cy) * pitch);
            let cos2 = f * f / (f * f + x * x + yy * yy);
            let expected = f64::from(p[1]) * cos2 * cos2;
            assert!((f64::from(v[1]) - expected).abs() <= 1.0, "({u}, {y})");
            checked += 1;
        }
    }
    assert!(checked > 500);
}

#[test]
fn nonlinear_response_is_8_bit_gamma() {
    let linear = render_frame(&lambertian(0.5, ""), THETA_L, SHUTTER);
    let scene = lambertian(0.5, "[effects.response]\ngamma = 2.2\n");
    let levels = render::file_levels(&scene);
    assert!(levels.nonlinear);
    assert_eq!((levels.black_level, levels.white_level), (0, 65535));
    let coded = render_frame(&scene, THETA_L, SHUTTER);
    for (l, c) in linear.data().iter().zip(coded.data()) {
        assert_eq!(c % 257, 0);
        let expected = (255.0 * (f64::from(*l) / 65535.0).powf(1.0 / 2.2)).round();
        assert_eq!(f64::from(c / 257), expected);
    }
}

#[test]
fn hot_pixels_are_stuck_at_white() {
    let count = |frame: &Frame16| {
        frame
            .data()
            .chunks_exact(3)
            .filter(|p| p.iter().all(|v| *v == 65535))
            .count()
    };
    let plain = render_frame(&lambertian(0.5, ""), THETA_L, SHUTTER);
    assert_eq!(count(&plain), 0);
    let hot = render_frame(
        &lambertian(0.5, "[effects.hot_pixels]\ncount = 25\n"),
        THETA_L,
        SHUTTER,
    );
    assert_eq!(count(&hot), 25);
    let differing = plain
        .data()
        .chunks_exact(3)
        .zip(hot.data().chunks_exact(3))
        .filter(|(a, b)| a != b)
        .count();
    assert_eq!(differing, 25);
}

#[test]
fn retro_reflection_brightens_only_the_sample() {
    let plain = render_frame(&lambertian(0.3, ""), THETA_L, SHUTTER);
    let retro = render_frame(
        &lambertian(
            0.3,
            "[effects.retro_reflection]\nkr = [40.0, 40.0, 40.0]\nwidth_deg = 30.0\n",
        ),
        THETA_L,
        SHUTTER,
    );
    let mut brighter = 0;
    for u in 0..400 {
        assert_eq!(plain.pixel(u, 89), retro.pixel(u, 89), "white unchanged");
        let (p, r) = (plain.pixel(u, 30), retro.pixel(u, 30));
        assert!(r[1] >= p[1]);
        if r[1] > p[1] + 100 {
            brighter += 1;
        }
    }
    assert!(brighter > 200);
}

#[test]
fn thin_film_is_goniochromatic() {
    // The interference peak moves to shorter wavelengths as the incidence grows.
    let peak = |cos0: f64| {
        (400..=700)
            .step_by(2)
            .map(|l| {
                (
                    l,
                    thin_film_reflectance(cos0, f64::from(l), 1.5, 2.5, 1.58, 156.0),
                )
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap()
    };
    let (normal, grazing) = (peak(1.0), peak(0.5));
    assert!((500..=540).contains(&normal.0), "{normal:?}");
    assert!(grazing.0 + 40 < normal.0, "{grazing:?} vs {normal:?}");
    assert!(normal.1 > 0.1 && normal.1 < 0.4);

    let scene = scene(
        "[sample]\nmodel = \"thin-film\"\nkd = [4.0, 12.0, 14.0]\nks = 2.0\nm = 0.12\nfilm_thickness_nm = 156.0\nfilm_index = 2.5\nsubstrate_index = 1.58\n",
    );
    // Camera-RGB colour of the specular reflection: bluer at larger angles.
    let csv = reference::reference_csv(&scene);
    let rgb_at = |t: f64| {
        let row = csv
            .lines()
            .find(|l| l.starts_with(&format!("{t},{t},")))
            .unwrap();
        let v: Vec<f64> = row.split(',').skip(2).map(|x| x.parse().unwrap()).collect();
        scene.camera_domain().rgb(&std::array::from_fn(|i| v[i]))
    };
    let (near, far) = (rgb_at(10.0), rgb_at(60.0));
    assert!(
        far[2] / far[1] > 1.3 * near[2] / near[1],
        "{near:?} {far:?}"
    );
    let frame = render_frame(&scene, THETA_L, SHUTTER * 0.1);
    let lit = (0..400).filter(|&u| frame.pixel(u, 30)[1] > 100).count();
    assert!(lit > 200);
}

#[test]
fn measured_table_renders_like_its_model() {
    let dir = tempfile::tempdir().unwrap();
    let lambert = lambertian(0.4, "");
    std::fs::write(
        dir.path().join("table.csv"),
        reference::reference_csv(&lambert),
    )
    .unwrap();
    let path = dir.path().join("scene.toml");
    std::fs::write(
        &path,
        format!("{SMALL}\n[sample]\nmodel = \"measured\"\npath = \"table.csv\"\n"),
    )
    .unwrap();
    let measured = Scene::load(&path).unwrap();
    let a = render_frame(&lambert, THETA_L, SHUTTER);
    let b = render_frame(&measured, THETA_L, SHUTTER);
    for (x, y) in a.data().iter().zip(b.data()) {
        assert!(x.abs_diff(*y) <= 1, "{x} vs {y}");
    }
}

#[test]
fn incidence_tables_match_spectral_integration() {
    use gonio_mock_hw::render::brdf::Geom;
    use gonio_mock_hw::scene::material::Material;
    for name in ["blue-green", "opal"] {
        let scene = Scene::builtin(name).unwrap();
        let domain = scene.camera_domain();
        let material = Material::new(scene.sample(), domain).unwrap();
        let mut worst: f64 = 0.0;
        for ti in (-80..=80).step_by(7) {
            for tr in (-80..=80).step_by(3) {
                let g = Geom::in_plane(f64::from(ti), f64::from(tr));
                let table = material.beta(&g);
                let exact = domain.rgb(&material.beta_spectrum(&g, domain));
                for c in 0..3 {
                    worst = worst.max((table[c] - exact[c]).abs() / exact[c]);
                }
            }
        }
        assert!(worst < 1e-4, "{name}: worst relative error {worst}");
    }
}

#[test]
fn bragg_flakes_rotate_the_hue_with_the_facet_incidence() {
    use gonio_mock_hw::render::brdf::Geom;
    use gonio_mock_hw::scene::material::{BraggBand, Material};
    // Bragg–Snell: the band centre λ0·√(1 − sin²θ/n²), hand values at θ = 0 and 45°.
    let band = BraggBand {
        wavelength_nm: 600.0,
        effective_index: 1.35,
        width_nm: 30.0,
    };
    let peak = |cos0: f64| {
        let r = band.spectrum(cos0);
        (0..r.len()).max_by(|&a, &b| r[a].total_cmp(&r[b])).unwrap()
    };
    assert_eq!(390 + 10 * peak(1.0), 600);
    let at_45 = 600.0 * (1.0f64 - 0.5 / (1.35 * 1.35)).sqrt();
    assert!((390.0 + 10.0 * peak(0.5f64.sqrt()) as f64 - at_45).abs() <= 5.0);
    // The opal scene's highlight turns from orange toward yellow as θL grows: at the
    // specular peak of θL the light meets the flakes at θd = |θL|/2.
    let scene = Scene::builtin("opal").unwrap();
    let material = Material::new(scene.sample(), scene.camera_domain()).unwrap();
    let ratio = |theta_l: f64| {
        let b = material.beta(&Geom::in_plane(theta_l / 2.0, theta_l / 2.0));
        b[0] / b[1]
    };
    assert!(
        ratio(-20.0) > 1.8 && ratio(-45.0) < 1.1,
        "{} {}",
        ratio(-20.0),
        ratio(-45.0)
    );
    assert!(ratio(-30.0) < ratio(-20.0) && ratio(-45.0) < ratio(-30.0));
}
