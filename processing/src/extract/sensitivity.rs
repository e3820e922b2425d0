//! Each sample's sensitivity to the setup's uncertain inputs: the white reflectance
//! scales β, its angular dependence scales it by u_f/f at the white's angle of incidence;
//! a geometric source is moved by ± one standard uncertainty and each sample's column
//! given the geometry the moved setup sees (slopes per radian of signed θh).

use rayon::prelude::*;

use super::layout::{ColumnGeometry, StripLayout};
use crate::geometry::{Setup, SetupView};
use crate::samples::{Sample, SampleUncertainty};
use crate::setup_uncertainty::Source;

/// One θL's stated samples as extraction made them: per sample its image column, the
/// geometry it was given and whether it was read from the strip's centre row.
pub(super) struct Stated<'a> {
    pub(super) layout: &'a StripLayout,
    pub(super) theta_l: f64,
    pub(super) columns: &'a [usize],
    pub(super) geometry: &'a [ColumnGeometry],
    pub(super) centre_row: &'a [bool],
}

/// `setup` with `source` moved by `delta` (its unit); the white is not part of the
/// geometry and is returned unchanged.
fn perturbed(setup: &Setup, source: Source, delta: f64) -> Setup {
    let mut s = setup.clone();
    match source {
        Source::WhiteReflectance | Source::WhiteFalloff => {}
        Source::CameraOffset => s.camera_offset_mm += delta,
        Source::CameraDistance => s.camera_distance_mm += delta,
        Source::LightDistance => s.light_distance_mm += delta,
        Source::CylinderTilt => s.cylinder_tilt_deg += delta,
        Source::ArmZero | Source::ArmAngle => s.arm_zero_offset_deg += delta,
        Source::CameraYaw => s.camera_yaw_deg += delta,
        Source::CameraRoll => s.camera_roll_deg += delta,
    }
    s
}

/// Samples each side of a point in the local line whose slope is β's derivative along
/// signed θh ([`slopes`]).
const SLOPE_NEIGHBOURS: usize = 3;

/// Per sample and channel, dβ/dθh (per radian of signed θh) along its θL: the slope of
/// the least-squares line through it and its [`SLOPE_NEIGHBOURS`] neighbours each side
/// (fewer at the ends), which averages the noise that a difference of two neighbours
/// would carry into the sensitivities. 0 where a channel is dropped or the points do not
/// spread in θh.
fn slopes(samples: &[Sample], half_angles: &[f64]) -> Vec<[f64; 3]> {
    (0..samples.len())
        .map(|i| {
            let near =
                i.saturating_sub(SLOPE_NEIGHBOURS)..(i + SLOPE_NEIGHBOURS + 1).min(samples.len());
            std::array::from_fn(|c| {
                let points: Vec<(f64, f64)> = near
                    .clone()
                    .filter_map(|k| Some((half_angles[k], samples[k].channel(c)?)))
                    .collect();
                let n = points.len() as f64;
                if samples[i].dropped[c] || n < 2.0 {
                    return 0.0;
                }
                let mean_h = points.iter().map(|p| p.0).sum::<f64>() / n;
                let mean_b = points.iter().map(|p| p.1).sum::<f64>() / n;
                let sxx: f64 = points.iter().map(|p| (p.0 - mean_h).powi(2)).sum();
                let sxy: f64 = points.iter().map(|p| (p.0 - mean_h) * (p.1 - mean_b)).sum();
                if sxx > 0.0 {
                    sxy / sxx
                } else {
                    0.0
                }
            })
        })
        .collect()
}

/// Columns from one knot to the next where the light and the camera face the surface: a
/// moved setup's geometry is computed at the knots and its change from the stated
/// geometry interpolated between them. Toward grazing, where the geometry bends faster,
/// knots are closer ([`Knots::new`]); `interpolated_geometry_agrees_with_the_computed_one`
/// bounds the error.
const KNOT_SPACING: f64 = 32.0;

/// A change of a column's geometry, both ways a column is read
/// ([`StripLayout::column_geometry`]), as [`ColumnGeometry::to_array`] differences.
type Change = [[f64; 8]; 2];

/// Knots over the stated samples' columns, with the stated geometry there.
struct Knots {
    columns: Vec<usize>,
    stated: Vec<Option<[ColumnGeometry; 2]>>,
}

impl Knots {
    /// Knots from one before `first` to two past `last`, the next one [`KNOT_SPACING`]·c²
    /// columns on (at least one), c the smaller of cos θi and cos θr at the knot: a
    /// column's angles change at a rate that grows as 1/c toward grazing, and the
    /// irradiance ratio as 1/c too, so the cubic's error grows there unless the knots
    /// close in (at c^1.5 it reaches 0.3 % of the change).
    fn new(layout: &StripLayout, view: &SetupView, first: usize, last: usize) -> Self {
        let step = |stated: &Option<[ColumnGeometry; 2]>| {
            let c = stated.map_or(0.0, |g| {
                let (i, r) = (g[0].theta_i.to_radians(), g[0].theta_r.to_radians());
                i.cos().min(r.cos()).max(0.0)
            });
            ((KNOT_SPACING * c * c) as usize).max(1)
        };
        let mut knots = Self {
            columns: Vec::new(),
            stated: Vec::new(),
        };
        let mut x = first.saturating_sub(step(&layout.column_geometry(view, first)));
        let mut past_last = 0;
        while past_last < 2 {
            let stated = layout.column_geometry(view, x);
            knots.columns.push(x);
            past_last += usize::from(x > last);
            x += step(&stated);
            knots.stated.push(stated);
        }
        knots
    }

    /// Per knot, how the geometry seen through `moved` differs from the stated one.
    fn changes(&self, layout: &StripLayout, moved: &SetupView) -> Vec<Option<Change>> {
        self.columns
            .iter()
            .zip(&self.stated)
            .map(|(&x, stated)| {
                let stated = stated.as_ref()?;
                let moved = layout.column_geometry(moved, x)?;
                Some(std::array::from_fn(|way| {
                    let (m, s) = (moved[way].to_array(), stated[way].to_array());
                    std::array::from_fn(|f| m[f] - s[f])
                }))
            })
            .collect()
    }

    /// Where column `x` falls among the knots: on one, or between the middle two of four
    /// consecutive knots with their Lagrange weights at `x` (cubic interpolation).
    fn place(&self, x: usize) -> Place {
        match self.columns.binary_search(&x) {
            Ok(k) => Place::Knot(k),
            Err(k) if k >= 2 && k + 1 < self.columns.len() => {
                let nodes: [f64; 4] = std::array::from_fn(|a| self.columns[k - 2 + a] as f64);
                let t = x as f64;
                let weights = std::array::from_fn(|a| {
                    (0..4)
                        .filter(|&b| b != a)
                        .map(|b| (t - nodes[b]) / (nodes[a] - nodes[b]))
                        .product::<f64>()
                });
                Place::Between(k - 2, weights)
            }
            Err(_) => Place::Outside,
        }
    }

    /// The geometry the moved setup of `changes` gives column `x` at `place`, read `way`
    /// (0 the rows' mean, 1 the centre row), whose stated geometry is `stated`: the
    /// stated one plus the change at the knot or interpolated between the knots around
    /// `x`. Where one of those knots is off the cylinder, or `x` lies before the second
    /// knot or past the one before last, it is computed at `x` itself; `None` if `x` is
    /// then off the cylinder.
    fn moved(
        changes: &[Option<Change>],
        (layout, view): (&StripLayout, &SetupView),
        (x, place, way, stated): (usize, &Place, usize, &ColumnGeometry),
    ) -> Option<ColumnGeometry> {
        let interpolated = match place {
            Place::Knot(k) => changes[*k].map(|c| add(stated, &c[way])),
            Place::Between(first, weights) => (|| {
                let mut change = [0.0; 8];
                for (w, knot) in weights.iter().zip(&changes[*first..*first + 4]) {
                    for (sum, v) in change.iter_mut().zip(&knot.as_ref()?[way]) {
                        *sum += w * v;
                    }
                }
                Some(add(stated, &change))
            })(),
            Place::Outside => None,
        };
        interpolated.or_else(|| layout.column_geometry(view, x).map(|g| g[way]))
    }
}

/// Where a column falls among the [`Knots`] ([`Knots::place`]).
enum Place {
    Knot(usize),
    /// The first of four knots and their weights.
    Between(usize, [f64; 4]),
    Outside,
}

/// `g` plus `change` ([`ColumnGeometry::to_array`] order).
fn add(g: &ColumnGeometry, change: &[f64; 8]) -> ColumnGeometry {
    let a = g.to_array();
    ColumnGeometry::from_array(std::array::from_fn(|f| a[f] + change[f]))
}

/// Fills each sample's [`SampleUncertainty::sources`]: how β at the sample's stated
/// geometry changes when each uncertain input moves by one standard uncertainty.
/// The white reflectance scales β. A geometric source changes where each pixel's value is
/// placed, and a little the value itself (the strips' irradiance ratio and the white's
/// angular factor): with the setup moved by ±u, each sample's column is given the moved
/// setup's geometry (read the same way, the rows' mean or the centre row; [`Knots`]); a
/// column whose value v goes to v′ and whose signed θh moves by Δ changes β at its stated
/// θh by (v′ − v) − Δ·dβ/dθh ([`slopes`] of the stated samples); half the difference of
/// the two signs is taken (central difference). The change of θd at a fixed θh (a
/// fraction of the source's own size) is left out. A column the moved setup puts off
/// the cylinder or past the grazing limit gets no change.
pub(super) fn add_sensitivities(
    setup: &Setup,
    stated: &Stated,
    grazing_limit_deg: f64,
    (samples, white_angular): (&mut [Sample], &[f64]),
) {
    let (Some(&first), Some(&last)) = (stated.columns.first(), stated.columns.last()) else {
        return;
    };
    let inputs = setup.inputs();
    let half_angles: Vec<f64> = samples.iter().map(|s| s.half_difference().0).collect();
    let slope = slopes(samples, &half_angles);
    let knots = Knots::new(stated.layout, &setup.view(stated.theta_l), first, last);
    let angular = setup.white_angular();
    let places: Vec<Place> = stated.columns.iter().map(|&x| knots.place(x)).collect();
    let stated_samples: &[Sample] = samples;
    let changes: Vec<(usize, Vec<[f64; 3]>)> = inputs
        .par_iter()
        .enumerate()
        .filter(|(_, input)| {
            !matches!(
                input.source,
                Source::WhiteReflectance | Source::WhiteFalloff
            ) && input.u[0] > 0.0
        })
        .map(|(j, input)| {
            let [plus, minus] = [1.0, -1.0].map(|sign| {
                let view = perturbed(setup, input.source, sign * input.u[0]).view(stated.theta_l);
                let changes = knots.changes(stated.layout, &view);
                (0..stated_samples.len())
                    .map(|i| {
                        let g = &stated.geometry[i];
                        let way = usize::from(stated.centre_row[i]);
                        let moved = Knots::moved(
                            &changes,
                            (stated.layout, &view),
                            (stated.columns[i], &places[i], way, g),
                        );
                        let Some(m) = moved else {
                            return [0.0; 3];
                        };
                        if m.theta_i.abs() > grazing_limit_deg
                            || m.theta_r.abs() > grazing_limit_deg
                        {
                            return [0.0; 3];
                        }
                        // v′/v: the strips' pixels are the same, their irradiance ratio
                        // and the white's angular factor are the moved geometry's.
                        let (factor, moved_factor) =
                            (angular.at(g.white_cos_i).0, angular.at(m.white_cos_i).0);
                        if !(factor > 0.0 && g.irradiance_ratio > 0.0) {
                            return [0.0; 3];
                        }
                        let ratio = m.irradiance_ratio / g.irradiance_ratio * moved_factor / factor;
                        let placed = Sample {
                            theta_i: m.theta_i,
                            theta_r: m.theta_r,
                            cosines: Some(m.cosines),
                            ..Sample::default()
                        };
                        let shift = placed.half_difference().0 - half_angles[i];
                        let s = &stated_samples[i];
                        std::array::from_fn(|c| {
                            s.channel(c)
                                .map_or(0.0, |v| v * (ratio - 1.0) - shift * slope[i][c])
                        })
                    })
                    .collect::<Vec<[f64; 3]>>()
            });
            let change = plus
                .iter()
                .zip(&minus)
                .map(|(p, m)| std::array::from_fn(|c| (p[c] - m[c]) / 2.0))
                .collect();
            (j, change)
        })
        .collect();
    // Source::ALL begins with the white reference.
    let white = inputs[0].u;
    let falloff = Source::WhiteFalloff.index();
    for (i, sample) in samples.iter_mut().enumerate() {
        let rgb = sample.rgb;
        let dropped = sample.dropped;
        let u = sample
            .uncertainty
            .get_or_insert_with(SampleUncertainty::default);
        u.sources[0] = std::array::from_fn(|c| rgb[c] * white[c]);
        u.sources[falloff] = rgb.map(|v| v * white_angular[i]);
        for (j, change) in &changes {
            u.sources[*j] = change[i];
        }
        for c in (0..3).filter(|&c| dropped[c]) {
            for source in &mut u.sources {
                source[c] = 0.0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Gold's full-size setup, turned and offset every way a setup can be.
    fn misaligned() -> Setup {
        serde_json::from_value(serde_json::json!({
            "cylinder_radius_mm": 40.0, "camera_distance_mm": 700.0,
            "light_distance_mm": 1000.0, "focal_length_mm": 85.0, "pixel_pitch_um": 6.1,
            "image_width": 3872, "image_height": 2592, "sample_row": 1190, "white_row": 1401,
            "camera_offset_mm": 1.5, "cylinder_tilt_deg": 0.5, "arm_zero_offset_deg": 0.3,
            "camera_yaw_deg": 0.2, "camera_roll_deg": 0.4
        }))
        .expect("a setup")
    }

    /// For every geometric source moved by ± its default uncertainty, from near-normal
    /// to grazing θL, every field of every column's interpolated geometry (both ways a
    /// column is read) is within 1e-4 of the largest change the move makes to that
    /// field over the columns, plus rounding.
    #[test]
    fn interpolated_geometry_agrees_with_the_computed_one() {
        let setup = misaligned();
        let layout = StripLayout::new(&setup, 3872, 2592, 0.0).expect("layout");
        for theta_l in [-20.0, -45.0, -70.0] {
            let view = setup.view(theta_l);
            let stated: Vec<(usize, [ColumnGeometry; 2])> = (0..3872)
                .filter_map(|x| Some((x, layout.column_geometry(&view, x)?)))
                .filter(|(_, g)| g[0].theta_i.abs() <= 80.0 && g[0].theta_r.abs() <= 80.0)
                .collect();
            let (first, last) = (stated[0].0, stated[stated.len() - 1].0);
            let knots = Knots::new(&layout, &view, first, last);
            for source in Source::ALL
                .into_iter()
                .filter(|s| !matches!(s, Source::WhiteReflectance | Source::WhiteFalloff))
            {
                for sign in [1.0, -1.0] {
                    let delta = sign * source.default_uncertainty();
                    let moved_view = perturbed(&setup, source, delta).view(theta_l);
                    let changes = knots.changes(&layout, &moved_view);
                    let (knots, changes, layout, moved_view) =
                        (&knots, &changes, &layout, &moved_view);
                    let pairs: Vec<([f64; 8], [f64; 8], [f64; 8])> = stated
                        .iter()
                        .flat_map(|(x, g)| {
                            let exact = layout.column_geometry(moved_view, *x);
                            (0..2).filter_map(move |way| {
                                let exact = exact?[way];
                                let moved = Knots::moved(
                                    changes,
                                    (layout, moved_view),
                                    (*x, &knots.place(*x), way, &g[way]),
                                )
                                .expect("interpolated where it is computed");
                                Some((g[way].to_array(), exact.to_array(), moved.to_array()))
                            })
                        })
                        .collect();
                    assert!(pairs.len() > 1000, "{source:?}: {} columns", pairs.len());
                    for f in 0..8 {
                        let largest = pairs
                            .iter()
                            .map(|(s, e, _)| (e[f] - s[f]).abs())
                            .fold(0.0, f64::max);
                        let worst = pairs
                            .iter()
                            .map(|(s, e, m)| (m[f] - e[f]).abs() - 1e-13 * s[f].abs())
                            .fold(0.0, f64::max);
                        assert!(
                            worst <= 1e-4 * largest,
                            "θL {theta_l}, {source:?} {delta}, field {f}: error {worst:e} of a change up to {largest:e}"
                        );
                    }
                }
            }
        }
    }
}
