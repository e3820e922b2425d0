//! Judging a model by the θL it did not see (leave-one-θL-out): for each θL of a scan
//! the model is fitted (robust method, no uncertainty) to the samples of every other θL
//! and scored at that θL's samples, whose measured β stand for the truth:
//! - the eq. 10 loss there, and its scale Σ_p ‖β_p‖ (the loss of predicting 0);
//! - ΔErr_p per channel (eq. 11) and the mean ΔE_u′v′ (eq. 13, through the camera's
//!   RGB → XYZ matrix), over all of the θL's points and over its specular lobe
//!   ([`lobe`]).
//!
//! Every point of the θL is scored with the channels it has ([`super::fold_score`]): a
//! dropped channel is missing, its point is not.
//!
//! The table in (θh, θd) ([`super::table`]) is judged the same way: each θL predicted
//! from the columns of the others ([`table_held_out`]), relative to the shape of the best
//! parametric candidate fitted without that θL.
#![doc = include_str!("held_out.md")]

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::fold_score::score;
pub use super::fold_score::{errors, lobe, Errors, Fold, LOBE_FRACTION};
use super::linear::nnls2;
use super::table::{Shape, Table, CHROMATICITY_WINDOWS};
use super::{fit_from, robust_minimum_near, FitError, FitOptions, FitResult, Start};
use crate::brdf::{Model, Roughness};
use crate::color::CameraModel;
use crate::samples::{distinct_theta_l, Sample, THETA_L_TOLERANCE};

/// A model with its roughness form: one candidate of a comparison.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Variant {
    pub model: Model,
    pub roughness: Roughness,
}

impl Variant {
    /// `model` with `roughness`.
    pub const fn new(model: Model, roughness: Roughness) -> Self {
        Variant { model, roughness }
    }

    /// `cook-torrance` for shared roughness, `cook-torrance/per-channel` otherwise.
    pub fn label(&self) -> String {
        match self.roughness {
            Roughness::Shared => self.model.name().to_string(),
            Roughness::PerChannel => format!("{}/{}", self.model, self.roughness),
        }
    }

    /// Robust fit options of this variant.
    pub fn options(self) -> FitOptions {
        let mut options = FitOptions::new(self.model);
        options.roughness = self.roughness;
        options
    }
}

/// The table's form as written in a candidate: `{"model": "table"}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct TableForm {
    model: TableName,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
enum TableName {
    Table,
}

/// What is judged: a parametric variant, or the table in (θh, θd) ([`super::table`]).
/// Written as the variant's `model` and `roughness`, or as `"model": "table"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Form {
    Parametric(Variant),
    Table(TableForm),
}

impl Form {
    /// The table.
    pub const TABLE: Form = Form::Table(TableForm {
        model: TableName::Table,
    });

    /// The variant's label, or `table`.
    pub fn label(&self) -> String {
        match self {
            Form::Parametric(v) => v.label(),
            Form::Table(_) => "table".into(),
        }
    }

    /// The parametric variant, `None` for the table.
    pub fn variant(&self) -> Option<Variant> {
        match *self {
            Form::Parametric(v) => Some(v),
            Form::Table(_) => None,
        }
    }
}

/// Every model with both roughness forms, in order of their number of parameters (7, 7,
/// 9, 9, 10, 12): the candidates of `gonio fit --model auto`.
pub const CANDIDATES: [Variant; 6] = [
    Variant::new(Model::CookTorrance, Roughness::Shared),
    Variant::new(Model::Ward, Roughness::Shared),
    Variant::new(Model::CookTorrance, Roughness::PerChannel),
    Variant::new(Model::Ward, Roughness::PerChannel),
    Variant::new(Model::CookTorranceFresnel, Roughness::Shared),
    Variant::new(Model::CookTorranceFresnel, Roughness::PerChannel),
];

/// The candidates of `gonio fit --model auto`: the parametric ones ([`CANDIDATES`]), then
/// the table, the most complex (judged with three θL or more only).
pub const AUTO_CANDIDATES: [Form; 7] = [
    Form::Parametric(CANDIDATES[0]),
    Form::Parametric(CANDIDATES[1]),
    Form::Parametric(CANDIDATES[2]),
    Form::Parametric(CANDIDATES[3]),
    Form::Parametric(CANDIDATES[4]),
    Form::Parametric(CANDIDATES[5]),
    Form::TABLE,
];

/// A variant (or the table) judged at every θL in turn.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOut {
    pub form: Form,
    /// The folds that were fitted and scored, in the samples' θL order.
    pub folds: Vec<Fold>,
    /// The θL whose fold failed, and why.
    pub failed: Vec<(f64, String)>,
    /// The table's form only: the table of every θL judged (its chromaticity window the
    /// one that predicted unseen θL best).
    pub table: Option<Table>,
    /// The table's form only: the median held-out ΔE_u′v′ over the specular lobe of the
    /// same table with a specular of one colour ([`one_specular_colour_lobe_uv`]).
    pub one_specular_colour_lobe_uv: Option<f64>,
    /// A parametric variant only: per θL left out, the shape ([`Shape`]) of its fit to the
    /// other θL, which a table judged beside it predicts relative to.
    pub shapes: Vec<(f64, Shape)>,
    /// A parametric variant only: its robust minimum on every θL judged, where its folds
    /// start from and where its fit to every sample starts from ([`super::fit_from`]);
    /// `None` where that search failed.
    pub(crate) start: Option<Start>,
    /// A parametric variant only: its fits' loss evaluations × their points (its minimum
    /// and every fold's fit), the work of judging it.
    pub point_evaluations: u64,
}

/// The median of `values` (mean of the middle two for an even count); `None` if empty.
pub fn median(values: &[f64]) -> Option<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    })
}

impl HeldOut {
    /// Σ fold losses / Σ fold scales: the relative eq. 10 error of predicting every θL
    /// from the others; `None` when a fold failed.
    pub fn relative_loss(&self) -> Option<f64> {
        if !self.failed.is_empty() || self.folds.is_empty() {
            return None;
        }
        let loss: f64 = self.folds.iter().map(|f| f.loss).sum();
        let scale: f64 = self.folds.iter().map(|f| f.scale).sum();
        (scale > 0.0).then(|| loss / scale)
    }

    fn errors(&self, lobe: bool) -> impl Iterator<Item = &Errors> {
        self.folds
            .iter()
            .filter_map(move |f| if lobe { f.lobe.as_ref() } else { Some(&f.all) })
    }

    /// Median over the folds of ΔE_u′v′, over all points or over the lobe.
    pub fn median_delta_e_uv(&self, lobe: bool) -> Option<f64> {
        median(
            &self
                .errors(lobe)
                .filter_map(|e| e.delta_e_uv)
                .collect::<Vec<_>>(),
        )
    }

    /// Median over the folds of ΔErr_p per channel, over all points or over the lobe.
    pub fn median_err_p(&self, lobe: bool) -> Option<[f64; 3]> {
        let channel = |c: usize| median(&self.errors(lobe).map(|e| e.err_p[c]).collect::<Vec<_>>());
        Some([channel(0)?, channel(1)?, channel(2)?])
    }

    /// The shape of the fit without θL `theta_l`.
    pub fn shape_without(&self, theta_l: f64) -> Option<&Shape> {
        self.shapes
            .iter()
            .find(|(t, _)| (t - theta_l).abs() <= THETA_L_TOLERANCE)
            .map(|(_, s)| s)
    }

    /// Folds whose fit kept a colour shift, of those that could.
    pub fn colour_shift_count(&self) -> (usize, usize) {
        let tested: Vec<bool> = self.folds.iter().filter_map(|f| f.colour_shift).collect();
        (tested.iter().filter(|&&k| k).count(), tested.len())
    }
}

/// The samples at θL `theta_l` (`held == true`) or at every other θL.
fn split(samples: &[Sample], theta_l: f64, held: bool) -> Vec<Sample> {
    samples
        .iter()
        .filter(|s| ((s.theta_l - theta_l).abs() <= THETA_L_TOLERANCE) == held)
        .copied()
        .collect()
}

/// The variants of one job of [`leave_one_theta_l_out`], fitted in turn to the same
/// samples: Cook–Torrance–Fresnel after Cook–Torrance of the same roughness when both are
/// judged, taking its fit as the tied form its colour-shift test falls back to
/// ([`fit_fresnel_given`]) instead of fitting it again; every other variant alone.
fn fit_groups(variants: &[Variant]) -> Vec<Vec<usize>> {
    let tied_of = |v: &Variant| {
        variants.iter().position(|u| {
            v.model == Model::CookTorranceFresnel
                && u.model == Model::CookTorrance
                && u.roughness == v.roughness
        })
    };
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for (i, v) in variants.iter().enumerate() {
        if tied_of(v).is_some() {
            continue;
        }
        let mut group = vec![i];
        group.extend(
            variants
                .iter()
                .enumerate()
                .filter(|(_, w)| tied_of(w) == Some(i))
                .map(|(j, _)| j),
        );
        groups.push(group);
    }
    groups
}

/// A θL's samples apart from the others: what its folds are fitted to and scored at.
struct Split {
    /// The samples of every other θL.
    others: Vec<Sample>,
    /// The θL's samples with a channel known ([`known`]).
    held: Result<Vec<Sample>, String>,
}

impl Split {
    fn of(samples: &[Sample], theta_l: f64) -> Self {
        Split {
            others: split(samples, theta_l, false),
            held: known(samples, theta_l),
        }
    }
}

/// The variants `group` of `variants` (see [`fit_groups`]) fitted without θL `theta_l`
/// (to `split.others`) and scored there, each with its fit's shape; each fit starts from
/// the variant's robust minimum on every θL (`starts`, [`fit_from`]; none where that
/// failed); with each fit's loss evaluations × its points (a Cook–Torrance–Fresnel fit
/// that takes the group's Cook–Torrance fit as its tied form counts only its own).
fn fold_group(
    split: &Split,
    variants: &[Variant],
    starts: &[Option<Start>],
    group: &[usize],
    theta_l: f64,
    camera: &CameraModel,
) -> Vec<(usize, FoldOutcome, u64)> {
    let mut tied: Option<FitResult> = None;
    group
        .iter()
        .map(|&v| {
            let mut options = variants[v].options();
            options.uncertainty = false;
            let tied_form = tied
                .as_ref()
                .filter(|_| options.model == Model::CookTorranceFresnel);
            let fitted = fit_from(&split.others, &options, starts[v].as_ref(), tied_form);
            let evaluations = fitted
                .as_ref()
                .map_or(0, |f| f.evaluations_beyond(tied_form));
            if options.model == Model::CookTorrance {
                tied = fitted.as_ref().ok().cloned();
            }
            let outcome = fitted
                .map_err(|e| e.to_string())
                .and_then(|f| scored(&split.held, &f, theta_l, camera));
            (v, outcome, evaluations * split.others.len() as u64)
        })
        .collect()
}

/// `fitted` (fitted without θL `theta_l`) scored at that θL's samples with a channel
/// known, `held`; its shape beside.
fn scored(
    held: &Result<Vec<Sample>, String>,
    fitted: &FitResult,
    theta_l: f64,
    camera: &CameraModel,
) -> FoldOutcome {
    let held = held.as_ref().map_err(Clone::clone)?;
    let estimated: Vec<[f64; 3]> = held.iter().map(|s| fitted.predict_sample(s)).collect();
    let mut scored = score(theta_l, held, &estimated, camera)?;
    scored.colour_shift = fitted.colour_shift.map(|c| c.fitted);
    Ok((scored, fitted.shape()))
}

/// The samples of θL `theta_l` with a channel known.
fn known(samples: &[Sample], theta_l: f64) -> Result<Vec<Sample>, String> {
    let held: Vec<Sample> = split(samples, theta_l, true)
        .into_iter()
        .filter(|s| s.dropped.contains(&false))
        .collect();
    if held.is_empty() {
        return Err(format!("θL {theta_l} has no point with a channel known"));
    }
    Ok(held)
}

/// The table judged like a model: each θL predicted from the table of the others'
/// columns ([`Table::without`]), for each chromaticity window of
/// [`CHROMATICITY_WINDOWS`]; the window kept is the one with the lowest median held-out
/// ΔE_u′v′ over all points (the narrowest on a tie). Each θL is predicted relative to the
/// shape of `base`'s fit without it (the best parametric candidate's; none: relative to
/// nothing, [`super::table`]). The model-free bound of a model's held-out error: no
/// model reaches below what its own data interpolate to, except by extrapolating better
/// beyond the measured θd.
pub fn table_held_out(samples: &[Sample], base: Option<&HeldOut>, camera: &CameraModel) -> HeldOut {
    // The windows are judged in parallel, and kept in order: the narrowest on a tie.
    let judged: Vec<HeldOut> = CHROMATICITY_WINDOWS
        .par_iter()
        .map(|&window| table_folds(samples, window, base, camera))
        .collect();
    let mut best: Option<(f64, HeldOut)> = None;
    for held in judged {
        let uv = held.median_delta_e_uv(false).unwrap_or(f64::INFINITY);
        if best.as_ref().is_none_or(|(b, _)| uv < *b) {
            best = Some((uv, held));
        }
    }
    let mut held = match best {
        Some((_, held)) => held,
        None => table_folds(samples, 0.0, base, camera),
    };
    held.one_specular_colour_lobe_uv = held
        .table
        .as_ref()
        .and_then(|table| one_specular_colour_lobe_uv(samples, table, base, camera));
    held
}

/// The median held-out ΔE_u′v′ over the specular lobe of `table` (of every θL of
/// `samples`) with a specular of one colour (`one_specular_colour`): each θL predicted
/// from the others' columns with their specular's colour replaced by the one colour they
/// share. It keeps each point's brightness, the diffuse under the lobe with whatever
/// colour it has at each θd, but not a specular colour that changes: where the highlight
/// changes colour with angle the full table predicts its chromaticity better; where it
/// does not (a dielectric's colourless specular over a coloured diffuse) both predict
/// alike. Predicted relative to `base`'s shapes as [`table_held_out`]. `None` when no fold
/// could be scored.
pub fn one_specular_colour_lobe_uv(
    samples: &[Sample],
    table: &Table,
    base: Option<&HeldOut>,
    camera: &CameraModel,
) -> Option<f64> {
    let folds: Vec<f64> = distinct_theta_l(samples)
        .into_par_iter()
        .filter_map(|t| {
            let held = known(samples, t).ok()?;
            let shape = base.and_then(|b| b.shape_without(t));
            let others = one_specular_colour(&table.without(t)?).relative_to(shape);
            let estimated: Vec<[f64; 3]> = held.iter().map(|s| others.predict_sample(s)).collect();
            score(t, &held, &estimated, camera).ok()?.lobe?.delta_e_uv
        })
        .collect();
    median(&folds)
}

/// `table` with a specular of one colour: every value becomes its nearest mix
/// a·D + b·S (a, b ≥ 0, least squares) of its column's diffuse colour D (the median of
/// the column's points off its lobe, [`lobe`]; of all its points where every one is on
/// it) and one specular colour S shared by every column (the sum over their lobes of what
/// rises above D, each channel clipped at 0). Only points with every channel known enter
/// D and S; a point missing a channel is kept as it is (its known channels leave a and b
/// free: any mix fits them).
fn one_specular_colour(table: &Table) -> Table {
    let rgb = |p: &[f64; 4]| [p[1], p[2], p[3]];
    let complete = |p: &&[f64; 4]| p.iter().all(|v| v.is_finite());
    let parts: Vec<([f64; 3], Vec<bool>)> = table
        .columns()
        .iter()
        .map(|column| {
            let values: Vec<[f64; 3]> = column.points.iter().filter(complete).map(rgb).collect();
            let in_lobe = lobe(&values);
            let off: Vec<&[f64; 3]> = values
                .iter()
                .zip(&in_lobe)
                .filter(|(_, &l)| !l)
                .map(|(v, _)| v)
                .collect();
            let pool = if off.is_empty() {
                values.iter().collect()
            } else {
                off
            };
            let diffuse = std::array::from_fn(|c| {
                median(&pool.iter().map(|v| v[c]).collect::<Vec<_>>()).unwrap_or(0.0)
            });
            (diffuse, in_lobe)
        })
        .collect();
    let mut specular = [0.0; 3];
    for (column, (diffuse, in_lobe)) in table.columns().iter().zip(&parts) {
        let points = column.points.iter().filter(complete);
        for (p, _) in points.zip(in_lobe).filter(|(_, &l)| l) {
            for c in 0..3 {
                specular[c] += (p[c + 1] - diffuse[c]).max(0.0);
            }
        }
    }
    let mut parts = parts.into_iter();
    table.with_values(|column| {
        let (diffuse, _) = parts.next().unwrap_or_default();
        column
            .points
            .iter()
            .map(|p| {
                if complete(&p) {
                    two_colours(&rgb(p), &diffuse, &specular)
                } else {
                    rgb(p)
                }
            })
            .collect()
    })
}

/// The mix a·`d` + b·`s` (a, b ≥ 0) nearest `y` in least squares.
fn two_colours(y: &[f64; 3], d: &[f64; 3], s: &[f64; 3]) -> [f64; 3] {
    let dot = |a: &[f64; 3], b: &[f64; 3]| (0..3).map(|c| a[c] * b[c]).sum::<f64>();
    let (a, b) = nnls2(dot(d, d), dot(d, s), dot(s, s), dot(d, y), dot(s, y));
    std::array::from_fn(|c| a * d[c] + b * s[c])
}

/// The table of `samples` with chromaticity window `window`, each θL predicted from the
/// others' columns relative to `base`'s shape without it.
fn table_folds(
    samples: &[Sample],
    window: f64,
    base: Option<&HeldOut>,
    camera: &CameraModel,
) -> HeldOut {
    let mut held = HeldOut {
        form: Form::TABLE,
        folds: Vec::new(),
        failed: Vec::new(),
        table: None,
        one_specular_colour_lobe_uv: None,
        shapes: Vec::new(),
        start: None,
        point_evaluations: 0,
    };
    let table = Table::new(samples, window).map_err(|e| e.to_string());
    let outcomes: Vec<(f64, Result<Fold, String>)> = distinct_theta_l(samples)
        .into_par_iter()
        .map(|t| {
            let outcome = match &table {
                Ok(table) => table_fold(
                    samples,
                    table,
                    t,
                    base.and_then(|b| b.shape_without(t)),
                    camera,
                ),
                Err(e) => Err(e.clone()),
            };
            (t, outcome)
        })
        .collect();
    for (t, outcome) in outcomes {
        match outcome {
            Ok(f) => held.folds.push(f),
            Err(e) => held.failed.push((t, e)),
        }
    }
    held.table = table.ok();
    held
}

/// The table of every other θL than `theta_l` scored at its samples, relative to `shape`.
fn table_fold(
    samples: &[Sample],
    table: &Table,
    theta_l: f64,
    shape: Option<&Shape>,
    camera: &CameraModel,
) -> Result<Fold, String> {
    let held = known(samples, theta_l)?;
    let others = table
        .without(theta_l)
        .ok_or_else(|| "no other θL to interpolate".to_string())?
        .relative_to(shape);
    let estimated: Vec<[f64; 3]> = held.iter().map(|s| others.predict_sample(s)).collect();
    score(theta_l, &held, &estimated, camera)
}

/// The variant of `variants` whose robust minimum `variant`'s is sought from: the same
/// model with shared roughness for one per channel, and Cook–Torrance of the same
/// roughness (else shared) for Cook–Torrance–Fresnel; `None` for the first ones searched.
fn near_of(variants: &[Variant], variant: Variant) -> Option<usize> {
    let model = match variant.model {
        Model::CookTorranceFresnel => Model::CookTorrance,
        model => model,
    };
    [variant.roughness, Roughness::Shared]
        .into_iter()
        .map(|roughness| Variant::new(model, roughness))
        .filter(|&v| v != variant)
        .find_map(|v| variants.iter().position(|&u| u == v))
}

/// The work of [`leave_one_theta_l_out`] as a graph of tasks on the pool: every
/// variant's robust minimum on `samples`, the shared Cook–Torrance and Ward by the full
/// search, every other as soon as the minimum of its [`near_of`] is found, by
/// Gauss–Newton steps from it ([`robust_minimum_near`]; the full search where they give
/// up): one roughness per channel and a specular colour at 90° start as the shared
/// roughness and the constant colour found, which they refine. A group of
/// [`fit_groups`] is fitted without each θL as soon as its variants' minima are found,
/// while other minima are still sought.
struct Graph<'a> {
    samples: &'a [Sample],
    variants: &'a [Variant],
    theta_l: &'a [f64],
    camera: &'a CameraModel,
    near: Vec<Option<usize>>,
    groups: Vec<Vec<usize>>,
    /// Each variant's minimum once sought (`None` inside where its search failed).
    starts: Vec<OnceLock<Option<Start>>>,
    /// Per group, how many of its variants' minima are still sought.
    waiting: Vec<AtomicUsize>,
    /// Per θL, its samples apart from the others, made by the first fold that needs them.
    splits: Vec<OnceLock<Split>>,
    /// Each fold's variant, θL (its index in `theta_l`) and outcome, as they end.
    outcomes: Mutex<Vec<(usize, usize, FoldOutcome)>>,
    /// Per variant, its fits' loss evaluations × their points so far.
    work: Vec<AtomicU64>,
}

impl<'a> Graph<'a> {
    fn new(
        samples: &'a [Sample],
        variants: &'a [Variant],
        theta_l: &'a [f64],
        camera: &'a CameraModel,
    ) -> Self {
        let groups = fit_groups(variants);
        Graph {
            samples,
            variants,
            theta_l,
            camera,
            near: variants.iter().map(|&v| near_of(variants, v)).collect(),
            waiting: groups.iter().map(|g| AtomicUsize::new(g.len())).collect(),
            groups,
            starts: variants.iter().map(|_| OnceLock::new()).collect(),
            splits: theta_l.iter().map(|_| OnceLock::new()).collect(),
            outcomes: Mutex::new(Vec::new()),
            work: variants.iter().map(|_| AtomicU64::new(0)).collect(),
        }
    }

    /// Runs every task; returns the minima, each variant's fold outcomes in θL order and
    /// its fits' loss evaluations × their points.
    fn run(self) -> (Vec<Option<Start>>, Vec<Folds>, Vec<u64>) {
        rayon::scope(|scope| {
            for v in (0..self.variants.len()).filter(|&v| self.near[v].is_none()) {
                let graph = &self;
                scope.spawn(move |scope| graph.search(scope, v));
            }
        });
        let starts = self.starts();
        let mut outcomes = self
            .outcomes
            .into_inner()
            .unwrap_or_else(|e| e.into_inner());
        outcomes.sort_by_key(|&(v, k, _)| (v, k));
        let mut by_variant: Vec<Folds> = vec![Vec::new(); self.variants.len()];
        for (v, k, outcome) in outcomes {
            by_variant[v].push((self.theta_l[k], outcome));
        }
        let work = self.work.into_iter().map(AtomicU64::into_inner).collect();
        (starts, by_variant, work)
    }

    /// Every variant's minimum found so far (`None` where not yet, or where it failed).
    fn starts(&self) -> Vec<Option<Start>> {
        self.starts
            .iter()
            .map(|s| s.get().copied().flatten())
            .collect()
    }

    /// Seeks variant `v`'s minimum, then starts what waited for it.
    fn search<'s>(&'s self, scope: &rayon::Scope<'s>, v: usize) {
        let from = self.near[v].and_then(|b| self.starts[b].get().copied().flatten());
        let found = robust_minimum_near(self.samples, &self.variants[v].options(), from.as_ref());
        let start = found.ok().map(|(start, evaluations)| {
            let points = evaluations * self.samples.len() as u64;
            self.work[v].fetch_add(points, Ordering::Relaxed);
            start
        });
        let _ = self.starts[v].set(start);
        for w in (0..self.variants.len()).filter(|&w| self.near[w] == Some(v)) {
            scope.spawn(move |scope| self.search(scope, w));
        }
        for (g, group) in self.groups.iter().enumerate() {
            if group.contains(&v) && self.waiting[g].fetch_sub(1, Ordering::AcqRel) == 1 {
                for k in 0..self.theta_l.len() {
                    scope.spawn(move |_| self.fold(group, k));
                }
            }
        }
    }

    /// `group` fitted without the `k`-th θL and scored there.
    fn fold(&self, group: &[usize], k: usize) {
        let t = self.theta_l[k];
        let split = self.splits[k].get_or_init(|| Split::of(self.samples, t));
        let done = fold_group(split, self.variants, &self.starts(), group, t, self.camera);
        let mut outcomes = self.outcomes.lock().unwrap_or_else(|e| e.into_inner());
        for (v, outcome, work) in done {
            self.work[v].fetch_add(work, Ordering::Relaxed);
            outcomes.push((v, k, outcome));
        }
    }
}

/// A fold scored with its fit's shape, or why it failed.
type FoldOutcome = Result<(Fold, Shape), String>;

/// A variant's fold outcomes by the θL left out.
type Folds = Vec<(f64, FoldOutcome)>;

/// Every variant judged at every θL of `samples` in turn, fits in parallel (one job per
/// θL and group of `fit_groups`). Needs two θL at least (each fit sees the others).
pub fn leave_one_theta_l_out(
    samples: &[Sample],
    variants: &[Variant],
    camera: &CameraModel,
) -> Result<Vec<HeldOut>, FitError> {
    let theta_l = distinct_theta_l(samples);
    if theta_l.len() < 2 {
        return Err(FitError::TooFewThetaL {
            count: theta_l.len(),
            needed: 2,
        });
    }
    // Each fold's fit starts from the variant's minimum on every θL, which it differs
    // from by one θL of several.
    let (starts, outcomes, work) = Graph::new(samples, variants, &theta_l, camera).run();
    Ok(variants
        .iter()
        .zip(outcomes)
        .enumerate()
        .map(|(v, (&variant, outcomes))| {
            let mut held = HeldOut {
                form: Form::Parametric(variant),
                folds: Vec::new(),
                failed: Vec::new(),
                table: None,
                one_specular_colour_lobe_uv: None,
                shapes: Vec::new(),
                start: starts[v],
                point_evaluations: work[v],
            };
            for (t, outcome) in outcomes {
                match outcome {
                    Ok((f, shape)) => {
                        held.folds.push(f);
                        held.shapes.push((t, shape));
                    }
                    Err(e) => held.failed.push((t, e)),
                }
            }
            held
        })
        .collect())
}

#[cfg(test)]
mod tests;
