//! `gonio simulate`: render every capture a scan of a scene would produce (all θL, all
//! bracket exposures, 16-bit TIFF + JSON sidecar), plus `setup.json`, `truth.json` and a
//! goniospectrophotometer-style `reference.csv`, in the scan directory layout.

use std::path::{Path, PathBuf};

use anyhow::Context;
use gonio_files::output::write_atomically;
use gonio_files::scan_layout::format_shutter;
use gonio_files::scan_layout::theta_dir_name;
use gonio_mock_hw::render::{self, reference};
use gonio_processing::geometry::Setup;
use gonio_processing::scan_plan::{self, ScanPlan};

use crate::progress;

/// Arguments of `gonio simulate`.
#[derive(clap::Args)]
pub struct Args {
    #[arg(long, help = SCENE_HELP)]
    pub scene: String,
    /// Output scan directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Light angles θL in degrees, comma-separated, instead of the scene's.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub theta_l: Option<Vec<f64>>,
    /// Seed of the noise and hot-pixel positions, instead of the scene's.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Bin the sensor N×N (image size divided by N) for fast previews and tests.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub binning: u32,
}

/// Help of a `--scene` option: every name of [`gonio_mock_hw::scene::Scene::BUILTIN`] (a test checks it).
pub const SCENE_HELP: &str = "Scene file (TOML), or a built-in scene: gold, red, blue-green, opal";

fn write_json(path: &Path, value: &serde_json::Value) -> anyhow::Result<()> {
    let mut text = serde_json::to_string_pretty(value)?;
    text.push('\n');
    write_atomically(path, text.as_bytes()).with_context(|| format!("writing {}", path.display()))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let out = args.out.clone();
    let (count, scene) = render_scan(args)?;
    println!(
        "{count} captures of scene `{scene}` written to {}",
        out.display()
    );
    Ok(())
}

/// Writes the scan `args` asks for; returns the number of captures and the scene's name.
pub fn render_scan(args: Args) -> anyhow::Result<(usize, String)> {
    let mut scene = gonio_mock_hw::scene_spec::load_scene(&args.scene)?;
    if args.binning != 1 {
        scene = scene.binned(args.binning).context("--binning")?;
    }
    if let Some(theta_l) = args.theta_l {
        scene.set_theta_l_deg(theta_l).context("--theta-l")?;
    }
    if let Some(seed) = args.seed {
        scene.set_seed(seed);
    }
    let out = &args.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;

    let setup: Setup = serde_json::from_value(scene.setup_json())
        .context("scene setup does not convert to the processing setup")?;
    write_json(&out.join("setup.json"), &serde_json::to_value(&setup)?)?;
    write_json(&out.join("truth.json"), &scene.truth_json())?;
    let plan = ScanPlan {
        theta_l: scene.theta_l_deg().to_vec(),
        bracket_s: Some(scene.bracket_s().to_vec()),
    };
    let plan_path = out.join(scan_plan::PLAN_FILE);
    write_atomically(&plan_path, plan.to_json_text().as_bytes())
        .with_context(|| format!("writing {}", plan_path.display()))?;
    let reference_path = out.join("reference.csv");
    write_atomically(&reference_path, reference::reference_csv(&scene).as_bytes())
        .with_context(|| format!("writing {}", reference_path.display()))?;

    let levels = render::file_levels(&scene);
    let total = scene.theta_l_deg().len() * scene.bracket_s().len();
    let bar = progress::bar(total as u64, "captures");
    for &theta_l in scene.theta_l_deg() {
        let dir = out.join(theta_dir_name(theta_l));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        for (index, &shutter_s) in scene.bracket_s().iter().enumerate() {
            bar.set_message(format!("θL {theta_l:.1}°, {}", format_shutter(shutter_s)));
            let frame = render::render_frame(&scene, theta_l, shutter_s);
            let image = dir.join(format!("exp_{index:02}.tiff"));
            frame
                .write_tiff(&image)
                .with_context(|| format!("writing {}", image.display()))?;
            let time = time::OffsetDateTime::now_utc()
                .format(&time::format_description::well_known::Rfc3339)?;
            let mut sidecar = serde_json::json!({
                "shutter_s": shutter_s,
                "iso": scene.camera().iso,
                "theta_l": theta_l,
                "camera": scene.camera().model,
                "time": time,
                "black_level": levels.black_level,
                "white_level": levels.white_level,
                "significant_bits": levels.significant_bits,
                "scene": scene.name(),
            });
            if levels.nonlinear {
                sidecar["response"] = "nonlinear".into();
            }
            write_json(&image.with_extension("json"), &sidecar)?;
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    Ok((total, scene.name().to_owned()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scene_help_names_every_built_in_scene() {
        for name in gonio_mock_hw::scene::Scene::BUILTIN {
            assert!(
                SCENE_HELP.contains(name),
                "{name} missing from {SCENE_HELP}"
            );
        }
    }
}
