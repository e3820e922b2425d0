//! Multi-angle geometries of effect-colour instruments in gonio's in-plane signed angles
//! (docs/ARCHITECTURE.md, "Multi-angle colour"): illumination at 45° from the normal,
//! the viewing direction given by its aspecular angle, the angle from the specular
//! direction, positive towards the illumination (ASTM E2194). With the anormal signed
//! angles of "Angles and geometry" (the specular direction at θr = θi), illumination
//! θi = 45°·s and view θr = (45° − as)·s, s = ±1 the side of the normal the light is on:
//! as 15° views at θr = 30°, as 45° along the normal, as 110° 65° on the light's side
//! (θr = −65°), as −15° at 60° beyond the specular. In (θh, θd): θh = (θi − θr)/2 = as·s/2,
//! θd = |θi + θr|/2 = |45° − as/2|.

/// The illumination angle of every geometry, degrees from the normal.
pub const ILLUMINATION_DEG: f64 = 45.0;

/// ASTM E2194 (metallic and pearlescent pigments, 45° illumination): 15°, 45°, 110°.
pub const ASTM_E2194: [f64; 3] = [15.0, 45.0, 110.0];

/// The six aspecular angles of 45° illumination that ASTM E2539 (interference pigments)
/// and six-angle instruments (BYK-mac i) use: −15°, 15°, 25°, 45°, 75°, 110°.
pub const ASTM_E2539: [f64; 6] = [-15.0, 15.0, 25.0, 45.0, 75.0, 110.0];

/// Largest |aspecular angle| a geometry may have: the view must stay above the surface,
/// |45° − as| < 90°.
pub const MAX_ASPECULAR_DEG: f64 = 130.0;

/// The aspecular angles (degrees) of `spec`: `astm-e2194`, `astm-e2539`, or a list of
/// angles `15,45,110`. Each within −40°…[`MAX_ASPECULAR_DEG`] (the view at most 85° from
/// the normal), no angle twice; the order is kept.
pub fn parse_geometry(spec: &str) -> Result<Vec<f64>, String> {
    match spec.trim().to_ascii_lowercase().as_str() {
        "astm-e2194" => return Ok(ASTM_E2194.to_vec()),
        "astm-e2539" => return Ok(ASTM_E2539.to_vec()),
        _ => {}
    }
    let mut angles: Vec<f64> = Vec::new();
    for field in spec.split(',').map(str::trim) {
        let angle: f64 = field.parse().map_err(|_| {
            format!("'{field}' is not an aspecular angle (astm-e2194, astm-e2539 or a list such as 15,45,110)")
        })?;
        if !(angle.is_finite() && (-40.0..=MAX_ASPECULAR_DEG).contains(&angle)) {
            return Err(format!(
                "aspecular angle {field}° is outside −40…{MAX_ASPECULAR_DEG}° (the view would be more than 85° from the normal)"
            ));
        }
        if angles.iter().any(|&a| (a - angle).abs() < 1e-9) {
            return Err(format!("aspecular angle {field}° is given twice"));
        }
        angles.push(angle);
    }
    Ok(angles)
}

/// In-plane (θi, θr) in degrees of aspecular angle `aspecular` with the light on side
/// `side` (+1: θi = +45°, −1: θi = −45°).
pub fn incidence_and_view(aspecular: f64, side: f64) -> (f64, f64) {
    let s = if side < 0.0 { -1.0 } else { 1.0 };
    // + 0.0 writes a view along the normal as 0, not −0.
    (
        s * ILLUMINATION_DEG,
        s * (ILLUMINATION_DEG - aspecular) + 0.0,
    )
}

/// Signed θh and θd (degrees) of aspecular angle `aspecular` on side `side`, as the
/// measured table in (θh, θd) labels its points (θh signed by θi − θr).
pub fn half_difference(aspecular: f64, side: f64) -> (f64, f64) {
    let (i, r) = incidence_and_view(aspecular, side);
    ((i - r) / 2.0, ((i + r) / 2.0).abs())
}
