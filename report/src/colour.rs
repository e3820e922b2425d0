//! The multi-angle colour section: CIELAB at the ASTM E2539 aspecular angles of 45°
//! illumination (D65, 10° observer), each coordinate with its expanded uncertainty, as
//! `gonio colour` computes it from the scan's model and its measured table, and a
//! swatch per angle (the sRGB display colour of its L*a*b*, marked where clipped).

use gonio_processing::color::geometry::ASTM_E2539;
use gonio_processing::color::observer::{Conditions, Observer};
use gonio_processing::color::srgb::swatch;
use gonio_processing::color::transform::ColourTransform;
use gonio_processing::color::CameraModel;
use gonio_processing::multi_angle::{colour, ColourReport, Coordinate, Measured, Origin};

use crate::html::{escape, table};
use crate::Scan;

/// The conditions the report states colour under (the colour command's default).
const CONDITIONS: Conditions = Conditions::D65Ten;

/// The scan's multi-angle colour, or why there is none.
pub(crate) fn scan_colour(scan: &Scan) -> Result<ColourReport, String> {
    let chosen = scan.chosen().ok_or("no fit")?;
    let measured = if scan.samples.is_empty() {
        None
    } else {
        Some(Measured::of(&chosen.fit, &scan.samples).map_err(|e| e.to_string())?)
    };
    let transform =
        ColourTransform::new(&CameraModel::builtin(), CONDITIONS).map_err(|e| e.to_string())?;
    colour(&chosen.fit, measured.as_ref(), &transform, &ASTM_E2539).map_err(|e| e.to_string())
}

/// `value ± U`, two decimals.
fn with_u(c: Coordinate) -> String {
    if c.value.is_finite() && c.expanded.is_finite() {
        format!("{:.2} ± {:.2}", c.value, c.expanded)
    } else {
        "–".into()
    }
}

/// The section.
pub fn section(scan: &Scan) -> String {
    if scan.chosen().is_none() {
        return String::new();
    }
    let report = match scan_colour(scan) {
        Ok(report) => report,
        Err(reason) => {
            return format!(
            "<section><h2>Multi-angle colour</h2><p class=\"warn\">not computed: {}</p></section>",
            escape(&reason)
        )
        }
    };
    let white = Observer::new(report.conditions).white();
    let header: Vec<String> = [
        "aspecular °",
        "from",
        "L*",
        "a*",
        "b*",
        "C*",
        "h °",
        "swatch (sRGB)",
    ]
    .map(String::from)
    .to_vec();
    let rows: Vec<Vec<String>> = report
        .angles
        .iter()
        .map(|a| {
            let shown = swatch(a.lab(), white);
            let mut cell = format!(
                "<span class=\"swatch\" style=\"background:{hex}\" title=\"{hex}\"></span>",
                hex = shown.hex()
            );
            if !shown.in_gamut {
                cell += " <span class=\"warn\">out of gamut</span>";
            }
            let mut origin = match a.origin {
                Origin::Data => "data",
                Origin::Model => "model",
            }
            .to_string();
            if a.beyond_data {
                origin += " <span class=\"warn\">beyond the data: not a reading</span>";
            }
            vec![
                format!("{}", a.aspecular),
                origin,
                with_u(a.l),
                with_u(a.a),
                with_u(a.b),
                with_u(a.c),
                with_u(a.h),
                cell,
            ]
        })
        .collect();
    let mut body = format!(
        "<p>{}, 45° illumination, values ± U (k = {}), from the {} model; \"data\" where the \
         geometry lies inside the measured range, \"model\" outside it. The camera RGB → XYZ \
         transform's own error, in the uncertainties: ΔE00 median {:.2}, p95 {:.2}. A \
         swatch is the sRGB display colour of the L*a*b*, not a measurement.</p>",
        report.conditions.name(),
        report.coverage_factor,
        escape(&report.model),
        report.transform.delta_e00_median,
        report.transform.delta_e00_p95
    );
    body += &table("colour", &header, &rows);
    if let Some(flop) = report.flop_index {
        body += &format!("<p>Flop index {}</p>", with_u(flop));
    }
    for note in &report.notes {
        body += &format!("<p class=\"muted\">{}</p>", escape(note));
    }
    format!("<section><h2>Multi-angle colour</h2>{body}</section>")
}
