//! The misalignment effect: scenes that do not name it render exactly as before it
//! existed; scenes that do are rendered by each pixel's own ray, checked against the
//! separable renderer where both apply and against tangent and rotation geometry
//! where only the general one does.

use gonio_mock_hw::render::{render_frame, Frame16};
use gonio_mock_hw::scene::Scene;

const SMALL: &str = include_str!("../scene_small.toml");
const LAMBERTIAN: &str = "[sample]\nmodel = \"lambertian\"\nkd = [40.0, 30.0, 20.0]\n";
const CT: &str =
    "[sample]\nmodel = \"cook-torrance\"\nkd = [9.0, 6.5, 2.0]\nks = [25.0, 20.0, 7.0]\nm = [0.2]\n";

fn scene(sample: &str, misalignment: Option<&str>) -> Scene {
    let effects = misalignment.map_or(String::new(), |m| format!("[effects.misalignment]\n{m}\n"));
    Scene::from_toml_str(&format!("{SMALL}\n{sample}\n{effects}")).unwrap()
}

/// FNV-1a over the frame's values, little-endian.
fn fnv(frame: &Frame16) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for v in frame.data() {
        for b in v.to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

#[test]
fn scenes_without_misalignment_render_exactly_as_before() {
    // Hashes of the renderer as it was before misalignments existed (commit 1c5da7c),
    // built-in scenes binned 8× with their own effects (noise, vignetting, thin film).
    let expected = [
        ("gold", -30.0, 0.125, 0xb0b8_6190_264a_e884_u64),
        ("gold", -45.0, 0.5, 0xe2da_fce8_3cf9_21d3),
        ("red", -30.0, 0.125, 0x182a_4f7e_98e7_7ee6),
        ("red", -45.0, 0.5, 0x876d_dc57_24c0_3b6a),
        ("blue-green", -30.0, 0.125, 0xad4e_d2ae_bfc5_dc3b),
        ("blue-green", -45.0, 0.5, 0xc8b4_65da_442c_66b3),
    ];
    for (name, theta_l, shutter, hash) in expected {
        let scene = Scene::builtin(name).unwrap().binned(8).unwrap();
        let frame = render_frame(&scene, theta_l, shutter);
        assert_eq!(fnv(&frame), hash, "{name} at θL {theta_l}, {shutter} s");
    }
}

/// The largest difference between two frames over the columns `columns` of `rows`.
fn largest_difference(a: &Frame16, b: &Frame16, rows: &[u32]) -> u16 {
    let mut worst = 0;
    for &y in rows {
        for x in 0..a.width() {
            for (p, q) in a.pixel(x, y).iter().zip(b.pixel(x, y)) {
                worst = worst.max(p.abs_diff(q));
            }
        }
    }
    worst
}

/// Rows well inside the two strips (away from their edges, where the general renderer's
/// bands on the cylinder and the separable renderer's image rows part).
const INNER_ROWS: [u32; 6] = [26, 30, 34, 85, 89, 93];

#[test]
fn a_zero_misalignment_renders_as_the_separable_renderer() {
    for theta_l in [-30.0, -60.0, 10.0] {
        let aligned = render_frame(&scene(CT, None), theta_l, 0.01);
        let general = render_frame(&scene(CT, Some("")), theta_l, 0.01);
        let lit = INNER_ROWS
            .iter()
            .flat_map(|&y| (0..aligned.width()).map(move |x| (x, y)))
            .filter(|&(x, y)| aligned.pixel(x, y)[1] > 1000)
            .count();
        assert!(lit > 600, "{lit} lit pixels at θL {theta_l}");
        // Same physics by two codes: equal up to the rounding of the counts.
        assert!(largest_difference(&aligned, &general, &INNER_ROWS) <= 1);
    }
}

#[test]
fn arm_zero_offset_and_light_distance_error_put_the_light_elsewhere() {
    let misaligned = scene(
        CT,
        Some("arm_zero_offset_deg = 0.3\nlight_distance_error_mm = 50.0"),
    );
    let moved = Scene::from_toml_str(
        &format!("{SMALL}\n{CT}")
            .replace("light_distance_mm = 1000.0", "light_distance_mm = 1050.0"),
    )
    .unwrap();
    let general = render_frame(&misaligned, -30.0, 0.01);
    let separable = render_frame(&moved, -29.7, 0.01);
    assert!(largest_difference(&general, &separable, &INNER_ROWS) <= 1);
    // And it matters: the nominal light gives another picture.
    let nominal = render_frame(&scene(CT, None), -30.0, 0.01);
    assert!(largest_difference(&general, &nominal, &INNER_ROWS) > 100);
}

/// First and last lit column of row `y` (green above `floor`).
fn lit_span(frame: &Frame16, y: u32, floor: u16) -> (u32, u32) {
    let lit: Vec<u32> = (0..frame.width())
        .filter(|&x| frame.pixel(x, y)[1] > floor)
        .collect();
    (lit[0], *lit.last().unwrap())
}

#[test]
fn camera_offset_yaw_and_distance_move_the_limbs_where_tangent_rays_fall() {
    // Light behind the camera (θL = 0) lights both limbs. A camera at (D, δ) turned by
    // ψ sees the cylinder's tangent rays at bearings β ± asin(r/|C|) from the line to
    // the axis; a bearing θ (counter-clockwise) falls at image x = f·tan(π + ψ − θ).
    // A camera distance error e puts the camera at D = 700 + e.
    let (r, f, pitch, cx) = (40.0f64, 85.0, 0.030, 199.5);
    for (offset, yaw, error) in [
        (3.0f64, 0.0f64, 0.0f64),
        (0.0, 0.5, 0.0),
        (-2.0, -0.3, 0.0),
        (0.0, 0.0, -50.0),
        (0.0, 0.0, 40.0),
        (2.0, 0.3, 25.0),
    ] {
        let d = 700.0 + error;
        let misaligned = scene(
            LAMBERTIAN,
            Some(&format!(
                "camera_offset_mm = {offset}\ncamera_yaw_deg = {yaw}\ncamera_distance_error_mm = {error}"
            )),
        );
        let frame = render_frame(&misaligned, 0.0, 0.01);
        let to_axis = (-offset).atan2(-d);
        let half = (r / d.hypot(offset)).asin();
        let column = |bearing: f64| {
            cx + f * (std::f64::consts::PI + f64::to_radians(yaw) - bearing).tan() / pitch
        };
        // The larger bearing points toward −y, the image's left.
        let (left, right) = (column(to_axis + half), column(to_axis - half));
        for y in [30, 89] {
            let (first, last) = lit_span(&frame, y, 20);
            // The first lit pixel centre lies within one pixel inside the limb.
            assert!(
                f64::from(first) >= left && f64::from(first) - left < 1.0,
                "offset {offset}, yaw {yaw}, distance error {error}: first lit {first}, limb {left}"
            );
            assert!(
                f64::from(last) <= right && right - f64::from(last) < 1.0,
                "offset {offset}, yaw {yaw}, distance error {error}: last lit {last}, limb {right}"
            );
        }
    }
}

#[test]
fn cylinder_tilt_and_camera_roll_rotate_the_picture_about_the_principal_point() {
    // With the camera on the world x axis, tilting the cylinder about that axis by τ
    // rotates the cylinder's picture by τ about the principal point (clockwise, top to
    // the right): an upright limb at x = ±w maps to x = (±w + y sin τ)/cos τ at height y.
    // Rolling the camera by τ (its right toward its up) turns the picture the same way.
    for misalignment in ["cylinder_tilt_deg = 2.0", "camera_roll_deg = 2.0"] {
        limbs_turned_by_two_degrees(misalignment);
    }
}

fn limbs_turned_by_two_degrees(misalignment: &str) {
    let (pitch, cx, cy) = (0.030, 199.5, 59.5);
    let tau = 2f64.to_radians();
    let upright = render_frame(&scene(LAMBERTIAN, None), 0.0, 0.01);
    let tilted = render_frame(&scene(LAMBERTIAN, Some(misalignment)), 0.0, 0.01);
    // The upright limb: exact, from the tangent ray (see the test above).
    let half = (40.0f64 / 700.0).asin();
    let w = 85.0 * half.tan() / pitch;
    let (first, last) = lit_span(&upright, 89, 20);
    assert!(f64::from(first) >= cx - w && f64::from(last) <= cx + w);
    // Rows near the strips' centres: their bands, tilted, still cover the limbs there.
    for y in [28u32, 30, 32, 87, 89, 91] {
        let up = cy - f64::from(y);
        let (first, last) = lit_span(&tilted, y, 20);
        let left = (-w + up * tau.sin()) / tau.cos() + cx;
        let right = (w + up * tau.sin()) / tau.cos() + cx;
        assert!(
            f64::from(first) >= left - 1e-9 && f64::from(first) - left < 1.0,
            "{misalignment}, row {y}: first lit {first}, limb {left}"
        );
        assert!(
            f64::from(last) <= right + 1e-9 && right - f64::from(last) < 1.0,
            "{misalignment}, row {y}: last lit {last}, limb {right}"
        );
    }
}

/// Rows of the white strip (79..=99) and of the sample strip (20..=40) well inside them.
const WHITE_ROWS: [u32; 3] = [85, 89, 93];
const SAMPLE_ROWS: [u32; 3] = [26, 30, 34];

#[test]
fn a_white_reflectance_error_scales_the_white_strip_only() {
    let nominal = render_frame(&scene(CT, Some("")), -30.0, 0.01);
    for error in [0.02, -0.05] {
        let misaligned = scene(CT, Some(&format!("white_reflectance_error = {error}")));
        // setup.json keeps stating the nominal white.
        assert_eq!(misaligned.setup_json()["white_reflectance"], 0.9);
        assert_eq!(misaligned.rendered_white_reflectance(), 0.9 * (1.0 + error));
        let frame = render_frame(&misaligned, -30.0, 0.01);
        let mut bright = 0;
        for &y in &WHITE_ROWS {
            for x in 0..frame.width() {
                for (p, q) in frame.pixel(x, y).iter().zip(nominal.pixel(x, y)) {
                    // Each count rounds its signal (to within ½): p = s(1 + e) ± ½ and
                    // q = s ± ½.
                    let expected = f64::from(q) * (1.0 + error);
                    assert!(
                        (f64::from(*p) - expected).abs() <= 0.5 * (2.0 + error.abs()),
                        "error {error} at ({x}, {y}): {p}, expected {expected}"
                    );
                    bright += usize::from(q > 5000);
                }
            }
        }
        assert!(bright > 300, "{bright} bright white values");
        assert_eq!(largest_difference(&frame, &nominal, &SAMPLE_ROWS), 0);
    }
}

#[test]
fn a_white_falloff_darkens_the_white_toward_grazing_only() {
    let nominal = render_frame(&scene(CT, Some("")), -30.0, 0.01);
    let falloff = 0.03;
    let frame = render_frame(
        &scene(CT, Some(&format!("white_falloff = {falloff}"))),
        -30.0,
        0.01,
    );
    // Each white value is its Lambertian one times 1 − a·(1 − cos θi) ∈ [1 − a, 1]
    // (counts round to within ½); facing the light it is unchanged, toward grazing
    // it is darker by nearly a.
    let (mut near_one, mut darkest) = (0, 1.0f64);
    for &y in &WHITE_ROWS {
        for x in 0..frame.width() {
            for (p, q) in frame.pixel(x, y).iter().zip(nominal.pixel(x, y)) {
                let (p, q) = (f64::from(*p), f64::from(q));
                assert!(
                    p <= q + 1.0 && p >= q * (1.0 - falloff) - 1.0,
                    "({x}, {y}): {p} against Lambertian {q}"
                );
                if q > 2000.0 {
                    let ratio = p / q;
                    near_one += usize::from(ratio > 0.999);
                    darkest = darkest.min(ratio);
                }
            }
        }
    }
    assert!(near_one > 10, "{near_one} values facing the light");
    assert!(darkest < 1.0 - 0.5 * falloff, "darkest ratio {darkest}");
    assert_eq!(largest_difference(&frame, &nominal, &SAMPLE_ROWS), 0);
}

#[test]
fn an_arm_angle_error_moves_the_light_of_its_own_theta_l_only() {
    let two_angles = |misalignment: &str| {
        Scene::from_toml_str(
            &format!("{SMALL}\n{CT}\n[effects.misalignment]\n{misalignment}\n")
                .replace("theta_l_deg = [-30.0]", "theta_l_deg = [-30.0, -45.0]"),
        )
        .unwrap()
    };
    let misaligned = two_angles("arm_zero_offset_deg = 0.1\narm_angle_errors_deg = [0.0, 0.4]");
    let zero_only = two_angles("arm_zero_offset_deg = 0.1");
    // θL −30° has no error of its own: the same frame as the zero offset alone.
    assert_eq!(
        render_frame(&misaligned, -30.0, 0.01),
        render_frame(&zero_only, -30.0, 0.01)
    );
    // An arm angle outside the scan's list gets no error either.
    assert_eq!(
        render_frame(&misaligned, -37.0, 0.01),
        render_frame(&zero_only, -37.0, 0.01)
    );
    // θL −45° has its light at −45 + 0.1 + 0.4 = −44.5°, which the separable renderer
    // draws with no misalignment at all.
    let general = render_frame(&misaligned, -45.0, 0.01);
    let separable = render_frame(&scene(CT, None), -44.5, 0.01);
    assert!(largest_difference(&general, &separable, &INNER_ROWS) <= 1);
    let without = render_frame(&zero_only, -45.0, 0.01);
    assert!(largest_difference(&general, &without, &INNER_ROWS) > 100);
    // The same θL to within the arm's G-code resolution takes the error too.
    assert!(
        largest_difference(
            &render_frame(&misaligned, -45.0002, 0.01),
            &general,
            &INNER_ROWS
        ) <= 2
    );
}
