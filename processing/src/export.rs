//! A fit for other tools (`docs/ARCHITECTURE.md`, "Export"): a Mitsuba 3 BSDF that
//! reproduces a Cook–Torrance or Ward fit, and the fitted BRDF tabulated on an in-plane
//! (θi, θr) grid.
//!
//! Units: β is the camera-RGB radiance factor (a perfect white gives the camera's white
//! RGB, G = 100), so the BRDF relative to a perfect white of each channel is
//! f_c = β_c/(π·W_c), W the white's camera RGB: exact in G (W_G = 100); in R and B the
//! white-balanced camera RGB, not a renderer's RGB primaries.
//!
//! Mitsuba 3 mapping (F = 1, `material = "none"`: a conductor with η = 0, k = 1 reflects
//! everything at every angle). Mitsuba's Beckmann distribution with `alpha` = m is
//! D_M = exp(−tan²α/m²)/(π m² cos⁴α) = D/π, and its microfacet BRDF is
//! S·D_M·G/(4 cos θi cos θr); `diffuse` is ρ/π; `blendbsdf` of weight ½ halves each, so the
//! written values are doubled:
//! - Cook–Torrance: ρ_c = Kd_c/W_c, S_c = 4·Ks_c/(π·W_c) (the paper's lobe is
//!   Ks·D·G/(π cos θi cos θr) = Ks·4/π·[D_M·G/(4 cos θi cos θr)]). Mitsuba's G is Smith's
//!   (Walter et al. 2007) where the paper's is the V-cavity one: equal to 1 at the specular
//!   peak below ~60°, they differ away from it and near grazing.
//! - Ward: ρ_c = Kd_c/(π·W_c), S_c = Ks_c/(π·W_c): Mitsuba 3 has no Ward BSDF; the
//!   Beckmann microfacet lobe matches Ward's at normal incidence and is brighter by
//!   1/cos θ at the specular direction θ (1.15 at 30°, 1.41 at 45°).
//! - Per-channel roughness: `alpha` is G's m (Mitsuba's roughness is one value).
//! - Cook–Torrance–Fresnel's colour changes with the angle between light and camera,
//!   which no Mitsuba 3 conductor parameter expresses: tabulate it instead.
//! - A fit that predicts with a measured table (`FitResult::table`) is refused too: its
//!   parametric fields are only its best parametric fit. Tabulated, the grid holds the
//!   table's predictions: measured between the θL of the scan, and beyond them the best
//!   parametric model's shape scaled to the table at its edge (see `fit::table`).
#![doc = include_str!("export.md")]

use std::f64::consts::PI;
use std::fmt::Write as _;

use crate::brdf::Model;
use crate::fit::FitResult;

/// Why a fit could not be exported.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExportError {
    #[error("{model} cannot be written as a Mitsuba 3 BSDF (its specular colour changes with angle); export it as a table")]
    NoMitsubaForm { model: Model },
    #[error("this fit predicts with a measured table in (θh, θd), which no Mitsuba 3 BSDF reproduces (its {model} fields are only the best parametric fit); export it as a table (--format table)")]
    TablePredictions { model: Model },
    #[error("the white's camera RGB {0:?} must be positive and finite")]
    BadWhite([f64; 3]),
    #[error("table grid: {0}")]
    BadGrid(String),
    #[error("the fit's {field} is not finite")]
    NonFinite { field: &'static str },
}

/// The parameters of the Mitsuba 3 BSDF written for a fit: a `blendbsdf` of weight ½
/// between `diffuse` (reflectance `diffuse`) and a Beckmann `roughconductor` (F = 1,
/// roughness `alpha`, `specular_reflectance` `specular`). Values are those written, i.e.
/// already doubled for the blend.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MitsubaBsdf {
    pub diffuse: [f64; 3],
    pub specular: [f64; 3],
    pub alpha: f64,
}

fn check_white(white: [f64; 3]) -> Result<(), ExportError> {
    if white.iter().all(|w| w.is_finite() && *w > 0.0) {
        Ok(())
    } else {
        Err(ExportError::BadWhite(white))
    }
}

/// The Mitsuba 3 parameters of a Cook–Torrance or Ward fit, relative to a perfect white
/// of camera RGB `white`.
pub fn mitsuba_bsdf(fit: &FitResult, white: [f64; 3]) -> Result<MitsubaBsdf, ExportError> {
    check_white(white)?;
    if fit.table.is_some() {
        return Err(ExportError::TablePredictions { model: fit.model });
    }
    let specular_scale = match fit.model {
        Model::CookTorrance => 4.0 / PI,
        Model::Ward => 1.0 / PI,
        model @ Model::CookTorranceFresnel => return Err(ExportError::NoMitsubaForm { model }),
    };
    // The diffuse radiance factor Kd·a (a = `Model::diffuse_weight`) over the white's.
    let diffuse_scale = fit.model.diffuse_weight();
    // The blend of weight ½ halves each lobe.
    let diffuse: [f64; 3] = std::array::from_fn(|c| 2.0 * diffuse_scale * fit.kd[c] / white[c]);
    let specular: [f64; 3] = std::array::from_fn(|c| 2.0 * specular_scale * fit.ks[c] / white[c]);
    let alpha = fit.params().m[1];
    let values = diffuse.iter().chain(&specular).chain([&alpha]);
    if values.into_iter().any(|v| !v.is_finite()) {
        return Err(ExportError::NonFinite {
            field: "kd, ks or m",
        });
    }
    Ok(MitsubaBsdf {
        diffuse,
        specular,
        alpha,
    })
}

/// The Mitsuba 3 scene file (XML, `<scene version="3.0.0">`) holding the fit's BSDF with
/// id `gonio-fit`, for `<ref id="gonio-fit"/>` from a shape.
pub fn mitsuba_xml(fit: &FitResult, white: [f64; 3]) -> Result<String, ExportError> {
    let b = mitsuba_bsdf(fit, white)?;
    let rgb = |v: [f64; 3]| format!("{:.9}, {:.9}, {:.9}", v[0], v[1], v[2]);
    let mut xml = String::new();
    let _ = writeln!(
        xml,
        "<!-- gonio {model} fit ({roughness} roughness): BRDF relative to a perfect white of \
         the camera's RGB (exact in G), F = 1; see docs/ARCHITECTURE.md, Export. -->",
        model = fit.model,
        roughness = fit.roughness
    );
    let _ = writeln!(xml, "<scene version=\"3.0.0\">");
    let _ = writeln!(xml, "    <bsdf type=\"blendbsdf\" id=\"gonio-fit\">");
    let _ = writeln!(xml, "        <float name=\"weight\" value=\"0.5\"/>");
    let _ = writeln!(xml, "        <bsdf type=\"diffuse\">");
    let _ = writeln!(
        xml,
        "            <rgb name=\"reflectance\" value=\"{}\"/>",
        rgb(b.diffuse)
    );
    let _ = writeln!(xml, "        </bsdf>");
    let _ = writeln!(xml, "        <bsdf type=\"roughconductor\">");
    let _ = writeln!(
        xml,
        "            <string name=\"distribution\" value=\"beckmann\"/>"
    );
    let _ = writeln!(
        xml,
        "            <float name=\"alpha\" value=\"{:.9}\"/>",
        b.alpha
    );
    let _ = writeln!(
        xml,
        "            <string name=\"material\" value=\"none\"/>"
    );
    let _ = writeln!(
        xml,
        "            <rgb name=\"specular_reflectance\" value=\"{}\"/>",
        rgb(b.specular)
    );
    let _ = writeln!(xml, "        </bsdf>");
    let _ = writeln!(xml, "    </bsdf>");
    let _ = writeln!(xml, "</scene>");
    Ok(xml)
}

/// One node of a BRDF table: in-plane angles (degrees, specular at θr = θi), β (camera
/// RGB) and f = β/(π·W) per channel (sr⁻¹, relative to a perfect white).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TableRow {
    pub theta_i: f64,
    pub theta_r: f64,
    pub beta: [f64; 3],
    pub brdf: [f64; 3],
}

/// The fit on the grid θi, θr ∈ {−max, −max + step, …, max} (degrees; 0 < step,
/// max < 90, at most 100 000 nodes), θi outer.
pub fn table(
    fit: &FitResult,
    white: [f64; 3],
    step_deg: f64,
    max_deg: f64,
) -> Result<Vec<TableRow>, ExportError> {
    check_white(white)?;
    if !(step_deg > 0.0 && step_deg.is_finite()) {
        return Err(ExportError::BadGrid(format!(
            "step {step_deg}° must be positive"
        )));
    }
    if !(max_deg > 0.0 && max_deg < 90.0) {
        return Err(ExportError::BadGrid(format!(
            "largest angle {max_deg}° must be in (0, 90)"
        )));
    }
    let per_axis = (2.0 * max_deg / step_deg).floor() + 1.0;
    if per_axis * per_axis > 100_000.0 {
        return Err(ExportError::BadGrid(format!(
            "{per_axis}² nodes exceed 100000: use a larger step"
        )));
    }
    let axis: Vec<f64> = (0..per_axis as usize)
        .map(|k| -max_deg + step_deg * k as f64)
        .collect();
    let mut rows = Vec::with_capacity(axis.len() * axis.len());
    for &theta_i in &axis {
        for &theta_r in &axis {
            let beta = fit.predict(theta_i, theta_r);
            if beta.iter().any(|b| !b.is_finite()) {
                return Err(ExportError::NonFinite {
                    field: "prediction",
                });
            }
            rows.push(TableRow {
                theta_i,
                theta_r,
                beta,
                brdf: std::array::from_fn(|c| beta[c] / (PI * white[c])),
            });
        }
    }
    Ok(rows)
}

/// The table as CSV: `theta_i,theta_r,beta_r,beta_g,beta_b,brdf_r,brdf_g,brdf_b`.
pub fn table_csv(rows: &[TableRow]) -> String {
    let mut out = String::from("theta_i,theta_r,beta_r,beta_g,beta_b,brdf_r,brdf_g,brdf_b\n");
    for r in rows {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{}",
            r.theta_i, r.theta_r, r.beta[0], r.beta[1], r.beta[2], r.brdf[0], r.brdf[1], r.brdf[2]
        );
    }
    out
}

/// The table as JSON: the fit it comes from, the white's camera RGB and the nodes.
pub fn table_json(fit: &FitResult, white: [f64; 3], rows: &[TableRow]) -> serde_json::Value {
    serde_json::json!({
        "fit": fit,
        "white_rgb": white,
        "units": {
            "angles": "degrees, in-plane, specular at theta_r = theta_i",
            "beta": "camera-RGB radiance factor (white G = 100)",
            "brdf": "sr^-1, beta / (pi * white_rgb): relative to a perfect white per channel",
        },
        "rows": rows.iter().map(|r| serde_json::json!({
            "theta_i": r.theta_i,
            "theta_r": r.theta_r,
            "beta": r.beta,
            "brdf": r.brdf,
        })).collect::<Vec<_>>(),
    })
}
