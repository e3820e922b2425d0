//! The report's sections other than the plots, each an HTML `<section>`.

use gonio_files::scan_layout::format_shutter;
use gonio_processing::geometry::Setup;
use serde_json::Value;

use crate::html::{escape, number, table};
use crate::{Scan, ScanFacts};

fn section(title: &str, body: &str) -> String {
    format!("<section><h2>{title}</h2>{body}</section>")
}

/// A JSON number as text to `digits` significant digits, "–" when absent.
fn num(value: Option<&Value>, digits: i32) -> String {
    value
        .and_then(Value::as_f64)
        .map_or("–".into(), |v| number(v, digits))
}

const CHANNELS: [&str; 3] = ["R", "G", "B"];

/// An RFC 3339 time to the second, in words a reader takes in (`2026-12-06 23:05:12Z`
/// for `2026-12-06T23:05:12.123456789Z`); anything else as it is.
fn short_time(rfc3339: &str) -> String {
    let Some((date, time)) = rfc3339.split_once('T') else {
        return rfc3339.to_owned();
    };
    let (clock, zone) = match time.find(['Z', 'z', '+', '-']) {
        Some(at) => time.split_at(at),
        None => (time, ""),
    };
    let whole = clock.split('.').next().unwrap_or(clock);
    format!("{date} {whole}{zone}")
}

/// Sample, scan, dates, camera, notes and software.
pub fn facts(
    scan: &Scan,
    facts: &ScanFacts,
    sample: &str,
    version: &str,
    generated: &str,
) -> String {
    let mut rows = vec![vec!["sample".into(), escape(sample)]];
    if let Some(id) = facts.id {
        rows.push(vec!["scan".into(), id.to_string()]);
    }
    if let Some(state) = &facts.state {
        rows.push(vec!["state".into(), escape(state)]);
    }
    for (name, time) in [
        ("queued", &facts.created),
        ("started", &facts.started),
        ("finished", &facts.finished),
    ] {
        if let Some(time) = time {
            rows.push(vec![name.into(), escape(&short_time(time))]);
        }
    }
    if let Some(captured) = &scan.captured {
        rows.push(vec![
            "captured".into(),
            format!(
                "{} – {}",
                escape(&short_time(&captured.first)),
                escape(&short_time(&captured.last))
            ),
        ]);
        rows.push(vec!["camera".into(), escape(&captured.cameras.join(", "))]);
    }
    if let Some(truth) = &scan.truth {
        let scene = truth.get("scene").and_then(Value::as_str).unwrap_or("?");
        rows.push(vec![
            "hardware".into(),
            format!("emulated (scene {})", escape(scene)),
        ]);
    }
    rows.push(vec![
        "notes".into(),
        facts
            .notes
            .as_deref()
            .filter(|n| !n.trim().is_empty())
            .map_or("<span class=\"muted\">none</span>".into(), escape),
    ]);
    rows.push(vec![
        "software".into(),
        format!("gonio {}", escape(version)),
    ]);
    rows.push(vec!["report made".into(), escape(&short_time(generated))]);
    section("Scan", &table("facts", &[], &rows))
}

/// The planned θL and bracket, and what the directory lacks of them.
pub fn plan(scan: &Scan) -> String {
    let mut body = String::new();
    match &scan.plan {
        Some(plan) => {
            let theta: Vec<String> = plan.theta_l.iter().map(|t| format!("{t}°")).collect();
            body += &format!("<p>θL: {}</p>", theta.join(", "));
            body += &match &plan.bracket_s {
                Some(b) => format!(
                    "<p>Bracket: {} exposures, {} s</p>",
                    b.len(),
                    b.iter()
                        .map(|s| number(*s, 3))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
                None => "<p>Bracket: chosen per θL by a metering capture</p>".into(),
            };
        }
        None => body += "<p class=\"muted\">The directory has no plan.json.</p>",
    }
    if let Some(captured) = &scan.captured {
        let items: String = captured
            .brackets
            .iter()
            .map(|(theta_l, shutters)| {
                let times: Vec<String> = shutters.iter().map(|&s| format_shutter(s)).collect();
                format!("<li>θL {theta_l}°: {}</li>", escape(&times.join(", ")))
            })
            .collect();
        body += &format!("<p>Exposures taken:</p><ul>{items}</ul>");
    }
    let theta_l = gonio_processing::samples::distinct_theta_l(&scan.samples);
    if !theta_l.is_empty() {
        body += &format!(
            "<p>{} samples from {} θL.</p>",
            scan.samples.len(),
            theta_l.len()
        );
    }
    if !scan.gaps.is_empty() {
        let items: String = scan
            .gaps
            .iter()
            .map(|g| format!("<li>{}</li>", escape(&g.to_string())))
            .collect();
        body += &format!("<p class=\"warn\">The scan directory is incomplete:</p><ul>{items}</ul>");
    }
    section("Plan and captures", &body)
}

/// setup.json's values (with where each came from, when it says) and the standard
/// uncertainties of the setup.
pub fn setup(scan: &Scan) -> String {
    let Some(json) = &scan.setup else {
        return section("Setup", "<p class=\"warn\">No setup.json.</p>");
    };
    let provenance = json.get("provenance");
    let mut rows = Vec::new();
    if let Some(object) = json.as_object() {
        for (key, value) in object {
            if matches!(key.as_str(), "calibration" | "provenance" | "uncertainty") {
                continue;
            }
            let shown = match value {
                Value::Number(n) => n.to_string(),
                Value::Null => "–".into(),
                other => escape(&other.to_string()),
            };
            let source = provenance
                .and_then(|p| p.get(key))
                .and_then(Value::as_str)
                .unwrap_or("");
            rows.push(vec![escape(key), shown, escape(source)]);
        }
    }
    let mut body = table(
        "setup",
        &["key".into(), "value".into(), "from".into()],
        &rows,
    );
    if json.get("calibration").is_some() {
        body += "<p>Calibrated from a scan's own captures (setup.json's <code>calibration</code> block).</p>";
    }
    match serde_json::from_value::<Setup>(json.clone()) {
        Ok(setup) => {
            let items: String = setup
                .uncertainty
                .inputs()
                .iter()
                .map(|i| format!("<li>{}</li>", escape(&i.describe())))
                .collect();
            body += &format!(
                "<h3>Standard uncertainties of the setup</h3><ul>{items}</ul>\
                 <p class=\"muted\">(default): setup.json states none; gonio's default is used.</p>"
            );
        }
        Err(e) => {
            body += &format!(
                "<p class=\"warn\">setup.json is not a valid setup: {}</p>",
                escape(&e.to_string())
            )
        }
    }
    section("Setup", &body)
}

/// The model the scan chose (or the first fit), its parameters and why.
pub fn model(scan: &Scan) -> String {
    let Some(chosen) = scan.chosen() else {
        return section(
            "Model",
            "<p class=\"warn\">No fit in the scan directory.</p>",
        );
    };
    let fit = &chosen.fit;
    let mut body = format!(
        "<p><b>{}</b>{} ({} roughness), from {}</p>",
        escape(&fit.model.to_string()),
        if fit.table.is_some() {
            ", predicting with the measured (θh, θd) table"
        } else {
            ""
        },
        escape(&fit.roughness.to_string()),
        chosen.name
    );
    let m = fit.m.per_channel();
    let mut rows = vec![
        row3("Kd", fit.kd),
        row3("Ks", fit.ks),
        row3("m", m),
        row3("ΔErr_p (fitted points)", fit.err_p),
    ];
    if let Some(ks_90) = fit.ks_90 {
        rows.insert(2, row3("Ks at 90°", ks_90));
    }
    if let Some(rho) = fit.rho_d {
        rows.push(row3("diffuse albedo ρd", rho));
    }
    body += &table(
        "params",
        &["parameter".into(), "R".into(), "G".into(), "B".into()],
        &rows,
    );
    body += &format!("<p>Loss (paper eq. 10): {}</p>", number(fit.loss, 4));
    if let Some(selection) = chosen.json.get("selection") {
        if let Some(reason) = selection.get("reason").and_then(Value::as_str) {
            body += &format!("<p>Why: {}</p>", escape(reason));
        }
        let shift = selection.get("colour_shift").and_then(Value::as_bool);
        body += &format!(
            "<p>Colour shift of the highlight across θL: <b>{}</b></p>",
            match shift {
                Some(true) => "reported",
                Some(false) => "not reported",
                None => "not judged",
            }
        );
    }
    section("Model", &body)
}

fn row3(name: &str, v: [f64; 3]) -> Vec<String> {
    let mut row = vec![escape(name)];
    row.extend(v.iter().map(|x| number(*x, 4)));
    row
}

/// The chosen fit's uncertainty budget in the GUM's layout: per quantity (a column) its
/// value, each source's standard uncertainty (a row each), the combined and expanded
/// uncertainty and the interval.
pub fn budget(scan: &Scan) -> String {
    let Some(budget) = scan
        .chosen()
        .and_then(|f| f.json.get("budget"))
        .or_else(|| scan.fits.iter().find_map(|f| f.json.get("budget")))
    else {
        let why = if scan.fits.is_empty() {
            "No budget: no fit in the scan directory."
        } else {
            "No budget: the samples carry no uncertainty columns."
        };
        return section(
            "Uncertainty budget",
            &format!("<p class=\"muted\">{why}</p>"),
        );
    };
    let Some(parameters) = budget.get("parameters").and_then(Value::as_object) else {
        return section(
            "Uncertainty budget",
            "<p class=\"warn\">Malformed budget.</p>",
        );
    };
    let mut sources: Vec<String> = Vec::new();
    let mut quantities: Vec<(String, &Value)> = Vec::new();
    for (name, list) in parameters {
        let Some(list) = list.as_array() else {
            continue;
        };
        for (c, b) in list.iter().enumerate() {
            let label = if list.len() == 3 {
                format!("{} {}", display_name(name), CHANNELS[c])
            } else {
                display_name(name)
            };
            for contribution in b
                .get("contributions")
                .and_then(Value::as_array)
                .into_iter()
                .flatten()
            {
                if let Some(source) = contribution.get("source").and_then(Value::as_str) {
                    if !sources.iter().any(|s| s == source) {
                        sources.push(source.to_owned());
                    }
                }
            }
            quantities.push((label, b));
        }
    }
    let k = num(budget.get("coverage_factor"), 3);
    // A column per quantity and a row per source, as a certificate's budget lists its
    // input quantities: a dozen sources by up to ten quantities fits a printed page.
    let mut header = vec![String::new()];
    header.extend(quantities.iter().map(|(label, _)| escape(label)));
    let row = |name: String, cell: &dyn Fn(&Value) -> String| -> Vec<String> {
        std::iter::once(name)
            .chain(quantities.iter().map(|(_, b)| cell(b)))
            .collect()
    };
    let mut rows = vec![row("value".into(), &|b| num(b.get("value"), 5))];
    for source in &sources {
        rows.push(row(
            format!("u({})", escape(&source.replace('_', " "))),
            &|b| {
                let u = b
                    .get("contributions")
                    .and_then(Value::as_array)
                    .and_then(|cs| {
                        cs.iter()
                            .find(|c| c.get("source").and_then(Value::as_str) == Some(source))
                    })
                    .and_then(|c| c.get("u"));
                num(u, 2)
            },
        ));
    }
    rows.push(row("u<sub>c</sub>".into(), &|b| num(b.get("combined"), 2)));
    rows.push(row(format!("U (k = {k})"), &|b| num(b.get("expanded"), 2)));
    rows.push(row("interval".into(), &|b| match b
        .get("interval")
        .and_then(Value::as_array)
        .map(|i| i.as_slice())
    {
        Some([lo, hi]) => format!("[{},<wbr> {}]", num(Some(lo), 5), num(Some(hi), 5)),
        _ => "–".into(),
    }));
    let mut body = table("budget", &header, &rows);
    body += &format!(
        "<p class=\"muted\">Standard uncertainties by source (JCGM 100, law of propagation); \
         U = k·u<sub>c</sub>. Residuals are {}× the stated noise.</p>",
        num(budget.get("residual_to_noise"), 3)
    );
    section("Uncertainty budget", &body)
}

fn display_name(key: &str) -> String {
    match key {
        "kd" => "Kd".into(),
        "ks" => "Ks".into(),
        "ks_90" => "Ks at 90°".into(),
        other => other.to_owned(),
    }
}

/// The model choice's candidates with their held-out errors (the θL a fit did not see).
pub fn held_out(scan: &Scan) -> String {
    let Some(selection) = scan.fits.iter().find_map(|f| f.json.get("selection")) else {
        return String::new();
    };
    let Some(candidates) = selection.get("candidates").and_then(Value::as_array) else {
        return String::new();
    };
    let chosen = selection.get("chosen").and_then(Value::as_u64);
    let rows: Vec<Vec<String>> = candidates
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let name = [c.get("model"), c.get("roughness")]
                .into_iter()
                .flatten()
                .filter_map(Value::as_str)
                .collect::<Vec<_>>()
                .join(" / ");
            let err_p = c.get("held_out_err_p").and_then(Value::as_array);
            let err_g = err_p.and_then(|e| e.get(1));
            let mark = if chosen == Some(i as u64) {
                " (chosen)"
            } else {
                ""
            };
            vec![
                format!("{}{mark}", escape(&name)),
                num(c.get("score"), 4),
                num(err_g, 3),
                num(c.get("held_out_delta_e_uv"), 3),
                num(c.get("held_out_delta_e_uv_lobe"), 3),
                c.get("error")
                    .and_then(Value::as_str)
                    .map(escape)
                    .unwrap_or_default(),
            ]
        })
        .collect();
    let body = table(
        "held-out",
        &[
            "candidate".into(),
            "held-out loss".into(),
            "ΔErr_p G".into(),
            "ΔE u′v′".into(),
            "ΔE u′v′ (lobe)".into(),
            "note".into(),
        ],
        &rows,
    )
        + "<p class=\"muted\">Each candidate fitted to all θL but one and scored on the θL it \
         did not see, every way round; medians.</p>";
    section("Held-out errors of the candidates", &body)
}

/// The other fits of the scan, one line each.
pub fn other_fits(scan: &Scan) -> String {
    let rows: Vec<Vec<String>> = scan
        .fits
        .iter()
        .skip(1)
        .map(|f| {
            let m = f.fit.m.per_channel();
            vec![
                escape(f.name),
                escape(&format!("{} ({})", f.fit.model, f.fit.roughness)),
                number(f.fit.kd[1], 4),
                number(f.fit.ks[1], 4),
                number(m[1], 4),
                number(f.fit.loss, 4),
            ]
        })
        .collect();
    if rows.is_empty() {
        return String::new();
    }
    let body = table(
        "fits",
        &[
            "file".into(),
            "model".into(),
            "Kd G".into(),
            "Ks G".into(),
            "m G".into(),
            "loss".into(),
        ],
        &rows,
    );
    section("Other fits of the scan", &body)
}

#[cfg(test)]
mod tests {
    use super::short_time;

    #[test]
    fn times_are_shown_to_the_second() {
        assert_eq!(
            short_time("2026-12-06T23:05:12.123456789Z"),
            "2026-12-06 23:05:12Z"
        );
        assert_eq!(
            short_time("2026-12-06T23:05:12+01:00"),
            "2026-12-06 23:05:12+01:00"
        );
        assert_eq!(short_time("yesterday"), "yesterday");
    }
}
