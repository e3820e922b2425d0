//! `gonio study --held-out`: every variant judged by leave-one-θL-out on the samples'
//! own θL (`gonio_processing::fit::held_out`), then the table in (θh, θd) (each θL
//! interpolated from the others: the model-free bound), and what `--model auto` chooses
//! among them.

use std::fmt::Write as _;

use anyhow::Context;
use gonio_processing::color::CameraModel;
use gonio_processing::fit::held_out::{table_held_out, Errors, Form, HeldOut};
use gonio_processing::fit::{
    best_parametric, choose_held_out, leave_one_theta_l_out, parameter_count, Variant,
};
use gonio_processing::samples::Sample;

use super::super::output::write_output_files;
use super::Args;
use crate::progress;

/// One CSV row's error columns: points, ΔErr_p R, G, B, ΔE_u′v′ (empty where undefined).
fn error_cells(errors: Option<&Errors>) -> String {
    match errors {
        Some(e) => format!(
            "{},{:.6},{:.6},{:.6},{}",
            e.points,
            e.err_p[0],
            e.err_p[1],
            e.err_p[2],
            e.delta_e_uv.map_or(String::new(), |d| format!("{d:.6}"))
        ),
        None => ",,,,".into(),
    }
}

/// The `model,roughness` cells of a form (the table's roughness empty).
fn form_cells(form: Form) -> String {
    match form {
        Form::Parametric(v) => format!("{},{}", v.model, v.roughness),
        Form::Table(_) => "table,".into(),
    }
}

/// `held_out.csv`: per variant (and the table) one row per θL left out, then its
/// medians over them.
fn csv(held: &[HeldOut]) -> String {
    let mut out = String::from(
        "model,roughness,theta_l_left_out,loss,scale,points,err_p_r,err_p_g,err_p_b,\
         delta_e_uv,lobe_points,lobe_err_p_r,lobe_err_p_g,lobe_err_p_b,lobe_delta_e_uv,\
         colour_shift,status\n",
    );
    for h in held {
        let head = form_cells(h.form);
        for f in &h.folds {
            let _ = writeln!(
                out,
                "{head},{},{:.6},{:.6},{},{},{},ok",
                f.theta_l,
                f.loss,
                f.scale,
                error_cells(Some(&f.all)),
                error_cells(f.lobe.as_ref()),
                f.colour_shift.map_or(String::new(), |k| k.to_string()),
            );
        }
        for (t, e) in &h.failed {
            let _ = writeln!(
                out,
                "{head},{t},,,,,,,,,,,,,,\"failed: {}\"",
                e.replace('"', "'")
            );
        }
        let medians = |lobe: bool| {
            h.median_err_p(lobe).map(|err_p| Errors {
                points: 0,
                err_p,
                delta_e_uv: h.median_delta_e_uv(lobe),
            })
        };
        let _ = writeln!(
            out,
            "{head},median,,,{},{},,median",
            error_cells(medians(false).as_ref()),
            error_cells(medians(true).as_ref()),
        );
    }
    out
}

pub fn run(args: &Args, samples: &[Sample], variants: &[Variant]) -> anyhow::Result<()> {
    let camera = CameraModel::builtin();
    // Simplest first: equal scores keep the simpler model.
    let mut variants = variants.to_vec();
    variants.sort_by_key(|v| parameter_count(v.model, v.roughness));
    let spinner = progress::spinner(format!(
        "{} variants, each θL left out in turn",
        variants.len()
    ));
    let judged = leave_one_theta_l_out(samples, &variants, &camera).and_then(|mut held| {
        let table = table_held_out(samples, best_parametric(&held), &camera);
        held.push(table);
        let chosen = choose_held_out(samples, &held, &camera)?;
        Ok((held, chosen))
    });
    spinner.finish_and_clear();
    let (held, chosen) = judged.with_context(|| format!("judging {}", args.samples.display()))?;
    let entries = held
        .iter()
        .map(|h| {
            // The form's `model` (and `roughness`) first, then the scores.
            let mut entry = serde_json::to_value(h.form)?;
            let scores = serde_json::json!({
                "relative_loss": h.relative_loss(),
                "median_delta_e_uv": h.median_delta_e_uv(false),
                "median_delta_e_uv_lobe": h.median_delta_e_uv(true),
                "median_err_p": h.median_err_p(false),
                "median_err_p_lobe": h.median_err_p(true),
                "folds": h.folds,
                "failed": h.failed.iter()
                    .map(|(t, e)| serde_json::json!({"theta_l": t, "error": e}))
                    .collect::<Vec<_>>(),
            });
            if let (Some(entry), serde_json::Value::Object(scores)) =
                (entry.as_object_mut(), scores)
            {
                entry.extend(scores);
            }
            Ok(entry)
        })
        .collect::<serde_json::Result<Vec<_>>>()?;
    // The chosen fit without its table (the selection says when the table won).
    let mut chosen_fit = chosen.clone();
    chosen_fit.table = None;
    let summary = serde_json::json!({
        "samples": samples.len(),
        "variants": entries,
        "chosen": chosen_fit,
    });
    let table = csv(&held);
    let json = serde_json::to_string_pretty(&summary)? + "\n";
    let written = write_output_files(&args.out, |dir| {
        let csv_path = dir.join("held_out.csv");
        std::fs::write(&csv_path, &table)?;
        let json_path = dir.join("held_out.json");
        std::fs::write(&json_path, &json)?;
        Ok(vec![csv_path, json_path])
    })?;
    let value = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
    let rgb =
        |v: Option<[f64; 3]>| v.map_or("-".to_string(), |e| e.map(|x| format!("{x:.4}")).join(" "));
    println!(
        "{}: each of {} θL predicted from the others; medians over the θL left out",
        args.samples.display(),
        held.first().map_or(0, |h| h.folds.len() + h.failed.len())
    );
    println!(
        "variant                            held-out loss  ΔE_u′v′ all   lobe  ΔErr_p R G B all       \
         lobe                    colour shift kept"
    );
    for h in &held {
        let (kept, tested) = h.colour_shift_count();
        println!(
            "{:<35} {:>12}  {:>11} {:>6}  {:<22} {:<22} {}",
            h.form.label(),
            value(h.relative_loss()),
            value(h.median_delta_e_uv(false)),
            value(h.median_delta_e_uv(true)),
            rgb(h.median_err_p(false)),
            rgb(h.median_err_p(true)),
            if tested > 0 {
                format!("{kept}/{tested}")
            } else {
                "-".into()
            },
        );
    }
    if let Some(selection) = &chosen.selection {
        println!("--model auto: {}", selection.reason);
    }
    for path in written {
        println!("wrote {}", path.display());
    }
    Ok(())
}
