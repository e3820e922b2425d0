//! A measured BRDF as a table in (signed θh, θd): the data-driven model of `gonio fit
//! --model table` and the last candidate of `--model auto`.
//!
//! An isotropic BRDF is close to a function of the half angle θh (between normal and
//! half vector) and the difference angle θd (between the half vector and the light or
//! camera) alone (Romeiro et al. 2008, *Passive reflectometry*): the specular lobe and
//! any colour change of a film or a pigment flake with the facet incidence are
//! functions of them. Every θL of a scan is one column of the table: in the plane of the
//! light θd = |θi + θr|/2 = |θL|/2 is constant along it, and its points spread along θh,
//! signed by the side of the specular peak they lie on (the sign of θi − θr; in-plane
//! θh = (θi − θr)/2), since a real sample need not be symmetric about its peak.
//!
//! **Prediction relative to a shape.** A table predicts relative to a parametric fit of
//! the same samples, its **shape** M ([`Shape`]: the best parametric candidate): per
//! channel β = M(θh, θd) · R(θh, θd), where R is the ratio of the stored β to M at the
//! stored points, linear in θh along each column between its two known values around θh,
//! then linear in θd between the two columns whose mean θd bracket θd. Between stored
//! points the lobe keeps the model's curvature, so a peak narrower than the spacing of
//! the points is not flattened as a straight line between them would; the ratio is
//! measured, so the table still reproduces its samples. **Beyond what was measured** — a
//! column's θh range, or the θd of the outermost columns — R is held at its value at the
//! edge: the shape of the model, scaled to the table at the edge. Nothing is
//! extrapolated from the data's own trend. Without a shape (M ≡ 1) the same rule is
//! linear interpolation of β and constant extrapolation.
//!
//! A column keeps every point of its θL with the channels it has: a channel dropped by
//! extraction (clipped, or too dark) is missing there (`null` in JSON), and that channel
//! is interpolated between its known values alone; the point's other channels are kept.
//! A channel no column knows is the shape's alone. Every k-th point is kept with k the
//! smallest stride that keeps each θL within [`super::stride::JUDGED_PER_THETA_L`] points
//! (neighbouring pixel columns differ little); points at the same θh are averaged, each
//! channel over its known values. The chromaticity of a column's points may be averaged
//! over a window of θh (its brightness kept point by point): noise in R, G, B makes a
//! single point's colour scatter where a material's colour changes slowly; the window
//! ([`CHROMATICITY_WINDOWS`]) is the one that predicts unseen θL best. Read from JSON, a
//! table is checked before it is used: at most [`MAX_COLUMNS`] columns of at most
//! [`MAX_POINTS_PER_COLUMN`] points each (counted while reading, before anything larger is
//! allocated), θh known and strictly increasing along each column, every value finite or
//! missing.
#![doc = include_str!("table.md")]

use serde::de::{self, SeqAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize};

use super::stride::{judged, JUDGED_PER_THETA_L};
use crate::brdf::{Cosines, Model, Params};
use crate::samples::{distinct_theta_l, Sample, THETA_L_TOLERANCE};

/// Most columns (θL) a table read from JSON may hold.
pub const MAX_COLUMNS: usize = 256;

/// Half-widths (degrees of θh) a table may average its columns' chromaticity over; the
/// one kept is the one that predicts the chromaticity of unseen θL best
/// (`held_out::table_held_out`).
pub const CHROMATICITY_WINDOWS: [f64; 5] = [0.0, 1.0, 2.0, 4.0, 8.0];

/// Most points a column read from JSON may hold: what a table built from samples keeps.
pub const MAX_POINTS_PER_COLUMN: usize = JUDGED_PER_THETA_L;

/// Why a table could not be built or read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TableError {
    #[error("no point with a channel known: the table would be empty")]
    Empty,
    #[error("column {column}: {what}")]
    Invalid { column: usize, what: String },
}

/// One θL of the table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Column {
    /// The θL it was measured at (degrees).
    pub theta_l: f64,
    /// Mean θd of its points (degrees).
    pub theta_d: f64,
    /// Its points, `[θh (degrees, signed), β_R, β_G, β_B]`, θh strictly increasing; a
    /// missing channel is NaN (`null` in JSON).
    #[serde(deserialize_with = "capped_points")]
    pub points: Vec<[f64; 4]>,
}

/// The table: the half-width its columns' chromaticity was averaged over, and its
/// columns in order of increasing θd.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "TableFile")]
pub struct Table {
    /// Degrees of θh (0: every point's own).
    chromaticity_window: f64,
    columns: Vec<Column>,
}

/// A table as read, before it is checked.
#[derive(Deserialize)]
struct TableFile {
    #[serde(default)]
    chromaticity_window: f64,
    #[serde(deserialize_with = "capped_columns")]
    columns: Vec<Column>,
}

impl TryFrom<TableFile> for Table {
    type Error = TableError;

    fn try_from(file: TableFile) -> Result<Self, TableError> {
        if file.columns.is_empty() {
            return Err(TableError::Empty);
        }
        if !(file.chromaticity_window.is_finite() && file.chromaticity_window >= 0.0) {
            return Err(TableError::Invalid {
                column: 0,
                what: "the chromaticity window is not a finite angle ≥ 0".into(),
            });
        }
        for (i, c) in file.columns.iter().enumerate() {
            let invalid = |what: &str| TableError::Invalid {
                column: i,
                what: what.to_owned(),
            };
            if !(c.theta_l.is_finite() && c.theta_d.is_finite()) {
                return Err(invalid("θL or θd is not finite"));
            }
            if c.points.is_empty() {
                return Err(invalid("no point"));
            }
            // The parser yields no infinity: a NaN is a `null`, a missing channel.
            if c.points
                .iter()
                .any(|p| !p[0].is_finite() || p.iter().any(|v| v.is_infinite()))
            {
                return Err(invalid("a θh is missing or a value is not finite"));
            }
            if c.points.windows(2).any(|w| w[1][0] <= w[0][0]) {
                return Err(invalid("θh is not strictly increasing"));
            }
            if i > 0 && c.theta_d < file.columns[i - 1].theta_d {
                return Err(invalid("θd is below the previous column's"));
            }
        }
        Ok(Table {
            chromaticity_window: file.chromaticity_window,
            columns: file.columns,
        })
    }
}

/// A sequence of at most `max` elements, refused as soon as it holds more.
struct Capped<T> {
    max: usize,
    what: &'static str,
    element: std::marker::PhantomData<T>,
}

impl<'de, T: Deserialize<'de>> Visitor<'de> for Capped<T> {
    type Value = Vec<T>;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "a list of at most {} {}", self.max, self.what)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<T>, A::Error> {
        let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(self.max));
        while let Some(v) = seq.next_element()? {
            if out.len() == self.max {
                return Err(de::Error::custom(format!(
                    "more than {} {}",
                    self.max, self.what
                )));
            }
            out.push(v);
        }
        Ok(out)
    }
}

/// A column's points, each value a number or `null` (missing: NaN).
fn capped_points<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<[f64; 4]>, D::Error> {
    let points: Vec<[Option<f64>; 4]> = d.deserialize_seq(Capped {
        max: MAX_POINTS_PER_COLUMN,
        what: "points in a table column",
        element: std::marker::PhantomData,
    })?;
    Ok(points
        .into_iter()
        .map(|p| p.map(|v| v.unwrap_or(f64::NAN)))
        .collect())
}

fn capped_columns<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Column>, D::Error> {
    d.deserialize_seq(Capped {
        max: MAX_COLUMNS,
        what: "table columns",
        element: std::marker::PhantomData,
    })
}

/// A point's half and difference angles (degrees): θh signed by the side of the
/// specular peak (`side`: θi ≥ θr), θd = acos(v·h).
pub fn half_difference(cosines: &Cosines, side: bool) -> (f64, f64) {
    let theta_h = cosines.n_dot_h.clamp(-1.0, 1.0).acos().to_degrees();
    let theta_d = cosines.v_dot_h.clamp(-1.0, 1.0).acos().to_degrees();
    (if side { theta_h } else { -theta_h }, theta_d)
}

/// [`half_difference`] of a sample.
fn sample_angles(s: &Sample) -> (f64, f64) {
    half_difference(&s.cosines(), s.theta_i >= s.theta_r)
}

/// The parametric model a table predicts relative to (see the module): a fit of the
/// same samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shape {
    pub model: Model,
    pub params: Params,
    /// The specular colour at 90° (`params.ks` for the models without one).
    pub ks_90: [f64; 3],
}

/// The shape's β is taken at least this fraction of its coefficients' scale (and never
/// 0), so that a ratio to it is defined where the model vanishes (grazing, far from a
/// lobe without diffuse).
const SHAPE_FLOOR: f64 = 1e-9;

impl Shape {
    /// β of the model at signed θh `h` and θd `d` (degrees) in the plane of the light
    /// (θi = θd + θh, θr = θd − θh), each channel at least `SHAPE_FLOOR` of its
    /// coefficients.
    pub fn at(&self, h: f64, d: f64) -> [f64; 3] {
        let beta = self
            .model
            .basis_at(&Cosines::in_plane(d + h, d - h))
            .evaluate_fresnel(&self.params, &self.ks_90);
        std::array::from_fn(|c| {
            let scale = self.params.kd[c].abs() + self.params.ks[c].abs() + self.ks_90[c].abs();
            let floor = SHAPE_FLOOR * scale + f64::MIN_POSITIVE;
            if beta[c].is_finite() {
                beta[c].max(floor)
            } else {
                floor
            }
        })
    }
}

impl Column {
    /// Channel `c`'s value `value(point, θd)` of the column's points (β, or its ratio to
    /// a shape) at signed θh `h`: linear between the two points around it that know
    /// channel `c`, the end one's beyond; `None` when the column knows no value of `c`.
    /// A missing value is NaN (a stored value is finite or missing).
    fn along(&self, h: f64, c: usize, value: &impl Fn(&[f64; 4], f64) -> f64) -> Option<f64> {
        let known = |p: &&[f64; 4]| !p[c + 1].is_nan();
        let k = self.points.partition_point(|p| p[0] <= h);
        let left = self.points[..k].iter().rev().find(known);
        let right = self.points[k..].iter().find(known);
        match (left, right) {
            (Some(a), Some(b)) => {
                let w = if b[0] > a[0] {
                    (h - a[0]) / (b[0] - a[0])
                } else {
                    0.0
                };
                let (ra, rb) = (value(a, self.theta_d), value(b, self.theta_d));
                Some(ra + w * (rb - ra))
            }
            (Some(p), None) | (None, Some(p)) => Some(value(p, self.theta_d)),
            (None, None) => None,
        }
    }
}

impl Table {
    /// The table of `samples` (see the module): one column per θL with a point with a
    /// channel known, every point with the channels it has (a dropped one NaN), each
    /// complete point's chromaticity averaged over `window` degrees of θh around it.
    pub fn new(samples: &[Sample], window: f64) -> Result<Table, TableError> {
        let (kept, _) = judged(samples);
        let mut columns: Vec<Column> = distinct_theta_l(&kept)
            .into_iter()
            .filter_map(|theta_l| {
                let angles: Vec<((f64, f64), [f64; 3])> = kept
                    .iter()
                    .filter(|s| (s.theta_l - theta_l).abs() <= THETA_L_TOLERANCE)
                    .filter(|s| s.dropped.contains(&false))
                    .map(|s| {
                        let rgb = std::array::from_fn(|c| s.channel(c).unwrap_or(f64::NAN));
                        (sample_angles(s), rgb)
                    })
                    .collect();
                if angles.is_empty() {
                    return None;
                }
                let theta_d = angles.iter().map(|((_, d), _)| d).sum::<f64>() / angles.len() as f64;
                let mut sorted: Vec<(f64, [f64; 3])> =
                    angles.into_iter().map(|((h, _), rgb)| (h, rgb)).collect();
                sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
                Some(Column {
                    theta_l,
                    theta_d,
                    points: smooth_chromaticity(merge_equal(&sorted), window),
                })
            })
            .collect();
        if columns.is_empty() {
            return Err(TableError::Empty);
        }
        columns.sort_by(|a, b| a.theta_d.total_cmp(&b.theta_d));
        Ok(Table {
            chromaticity_window: window.max(0.0),
            columns,
        })
    }

    /// The half-width (degrees of θh) its chromaticity was averaged over.
    pub fn chromaticity_window(&self) -> f64 {
        self.chromaticity_window
    }

    /// Its columns, in order of increasing θd.
    pub fn columns(&self) -> &[Column] {
        &self.columns
    }

    /// Its stored β values (the known channels of its points).
    pub fn values(&self) -> usize {
        self.columns
            .iter()
            .flat_map(|c| &c.points)
            .map(|p| p[1..].iter().filter(|v| v.is_finite()).count())
            .sum()
    }

    /// The table without the column of θL `theta_l`; `None` if nothing would be left.
    pub fn without(&self, theta_l: f64) -> Option<Table> {
        let columns: Vec<Column> = self
            .columns
            .iter()
            .filter(|c| (c.theta_l - theta_l).abs() > THETA_L_TOLERANCE)
            .cloned()
            .collect();
        (!columns.is_empty()).then_some(Table {
            chromaticity_window: self.chromaticity_window,
            columns,
        })
    }

    /// The same table with each column's values replaced by `values(column)`: one
    /// `[R, G, B]` per point in order (θh kept; a column given fewer keeps the rest).
    pub fn with_values(&self, mut values: impl FnMut(&Column) -> Vec<[f64; 3]>) -> Table {
        let columns = self
            .columns
            .iter()
            .map(|column| {
                let new = values(column);
                let mut column = column.clone();
                for (p, v) in column.points.iter_mut().zip(new) {
                    p[1..].copy_from_slice(&v);
                }
                column
            })
            .collect();
        Table {
            chromaticity_window: self.chromaticity_window,
            columns,
        }
    }

    /// β at signed θh `h` and θd `d` (degrees) relative to `shape` (see the module).
    pub fn predict(&self, h: f64, d: f64, shape: Option<&Shape>) -> [f64; 3] {
        let model = shape.map(|s| s.at(h, d));
        relative(model, |c| {
            self.interpolate(h, d, c, &|p: &[f64; 4], theta_d| {
                p[c + 1] / shape.map_or(1.0, |s| s.at(p[0], theta_d)[c])
            })
        })
    }

    /// The table relative to `shape`, for many predictions with the same shape: each
    /// stored value divided by the shape at its point once, not at every prediction.
    pub fn relative_to(&self, shape: Option<&Shape>) -> RelativeTable {
        let ratios = match shape {
            None => self.clone(),
            Some(s) => self.with_values(|column| {
                column
                    .points
                    .iter()
                    .map(|p| {
                        let m = s.at(p[0], column.theta_d);
                        std::array::from_fn(|c| p[c + 1] / m[c])
                    })
                    .collect()
            }),
        };
        RelativeTable {
            ratios,
            shape: shape.copied(),
        }
    }

    /// Channel `c`'s `value` at (`h`, `d`): linear in θd between the two columns around
    /// `d` that know the channel ([`Column::along`]), the nearest one's beyond; `None`
    /// when no column knows it.
    fn interpolate(
        &self,
        h: f64,
        d: f64,
        c: usize,
        value: &impl Fn(&[f64; 4], f64) -> f64,
    ) -> Option<f64> {
        let k = self.columns.partition_point(|col| col.theta_d <= d);
        let at = |col: &Column| Some((col.theta_d, col.along(h, c, value)?));
        let below = self.columns[..k].iter().rev().find_map(at);
        let above = self.columns[k..].iter().find_map(at);
        match (below, above) {
            (Some((d0, r0)), Some((d1, r1))) => {
                let span = d1 - d0;
                let w = if span > 0.0 { (d - d0) / span } else { 0.0 };
                Some(r0 + w * (r1 - r0))
            }
            (Some((_, r)), None) | (None, Some((_, r))) => Some(r),
            (None, None) => None,
        }
    }

    /// β at a point given by its cosines, on the side `side` (θi ≥ θr) of the peak.
    pub fn predict_at(&self, cosines: &Cosines, side: bool, shape: Option<&Shape>) -> [f64; 3] {
        let (h, d) = half_difference(cosines, side);
        self.predict(h, d, shape)
    }

    /// β at a sample's point.
    pub fn predict_sample(&self, s: &Sample, shape: Option<&Shape>) -> [f64; 3] {
        let (h, d) = sample_angles(s);
        self.predict(h, d, shape)
    }
}

/// β relative to the model M from its ratio R (see the module): M·R per channel, M
/// alone where no column knows the channel; without a model, R, 0 where unknown.
fn relative(model: Option<[f64; 3]>, ratio: impl Fn(usize) -> Option<f64>) -> [f64; 3] {
    std::array::from_fn(|c| match model {
        Some(m) => m[c] * ratio(c).unwrap_or(1.0),
        None => ratio(c).unwrap_or(0.0),
    })
}

/// A table relative to one shape ([`Table::relative_to`]): its values' ratios to the
/// shape, which [`Table::predict`] would find at every prediction. Predicts the same.
pub struct RelativeTable {
    ratios: Table,
    shape: Option<Shape>,
}

impl RelativeTable {
    /// β at a sample's point, as [`Table::predict_sample`] with the table's shape.
    pub fn predict_sample(&self, s: &Sample) -> [f64; 3] {
        let (h, d) = sample_angles(s);
        let model = self.shape.map(|s| s.at(h, d));
        relative(model, |c| {
            self.ratios
                .interpolate(h, d, c, &|p: &[f64; 4], _| p[c + 1])
        })
    }
}

/// A column's points with each point's chromaticity replaced by that of the sum of its
/// points within `window` degrees of θh (its own R + G + B kept): the brightness keeps
/// every point's detail, the colour is averaged over the window (over its points with
/// every channel known). Where that sum or the point's own is not positive, or the point
/// misses a channel, it is kept as it is.
fn smooth_chromaticity(points: Vec<[f64; 4]>, window: f64) -> Vec<[f64; 4]> {
    if window <= 0.0 {
        return points;
    }
    points
        .iter()
        .map(|p| {
            let lo = points.partition_point(|q| q[0] < p[0] - window);
            let hi = points.partition_point(|q| q[0] <= p[0] + window);
            let mut sum = [0.0; 3];
            for q in points[lo..hi]
                .iter()
                .filter(|q| q.iter().all(|v| v.is_finite()))
            {
                for (c, s) in sum.iter_mut().enumerate() {
                    *s += q[c + 1];
                }
            }
            let total: f64 = sum.iter().sum();
            let own = p[1] + p[2] + p[3];
            if total > 0.0 && own > 0.0 && own.is_finite() {
                [
                    p[0],
                    own * sum[0] / total,
                    own * sum[1] / total,
                    own * sum[2] / total,
                ]
            } else {
                *p
            }
        })
        .collect()
}

/// Points sorted by θh with those at equal θh averaged, each channel over its known
/// (finite) values, missing (NaN) where none is.
fn merge_equal(sorted: &[(f64, [f64; 3])]) -> Vec<[f64; 4]> {
    let mut out: Vec<[f64; 4]> = Vec::with_capacity(sorted.len());
    let mut i = 0;
    while i < sorted.len() {
        let h = sorted[i].0;
        let same = sorted[i..].iter().take_while(|p| p.0 == h).count();
        let mean = |c: usize| {
            let known: Vec<f64> = sorted[i..i + same]
                .iter()
                .map(|p| p.1[c])
                .filter(|v| v.is_finite())
                .collect();
            if known.is_empty() {
                f64::NAN
            } else {
                known.iter().sum::<f64>() / known.len() as f64
            }
        };
        out.push([h, mean(0), mean(1), mean(2)]);
        i += same;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_columns() -> Vec<Sample> {
        let mut samples = Vec::new();
        for (theta_l, level) in [(-20.0, 10.0), (-40.0, 30.0)] {
            for theta_i in [-10.0, -5.0, 0.0, 5.0] {
                let rgb = [level + theta_i, level, 1.0];
                samples.push(Sample::in_plane(theta_l, theta_i, theta_l - theta_i, rgb));
            }
        }
        samples
    }

    #[test]
    fn it_interpolates_in_theta_h_then_in_theta_d_and_holds_its_ends() {
        let table = Table::new(&two_columns(), 0.0).unwrap();
        let c = table.columns();
        assert_eq!(c.len(), 2);
        // θd = |θL|/2 in the plane; columns in order of θd.
        assert!((c[0].theta_d - 10.0).abs() < 1e-9 && (c[1].theta_d - 20.0).abs() < 1e-9);
        // θL −20, θi 0: θr −20, θh = +10°.
        let at = table.predict(10.0, 10.0, None);
        assert!((at[0] - 10.0).abs() < 1e-9, "{at:?}");
        // Halfway in θd, between two points in θh.
        let mid = table.predict(12.5, 15.0, None);
        let expected = 0.5 * ((10.0 + 2.5) + (30.0 + 2.5 - 10.0));
        assert!(
            (mid[0] - expected).abs() < 1e-9 && (mid[1] - 20.0).abs() < 1e-9,
            "{mid:?}"
        );
        // Without a shape, beyond the measured θd and θh: the nearest column, its end point.
        assert_eq!(
            table.predict(1e3, 80.0, None),
            table.predict(1e3, 20.0, None)
        );
        assert_eq!(table.predict(-1e3, 0.0, None)[1], 10.0);
        assert_eq!(table.without(-20.0).unwrap().columns().len(), 1);
        assert!(table.without(-20.0).unwrap().without(-40.0).is_none());
    }

    #[test]
    fn a_dropped_channel_is_missing_and_equal_theta_h_averaged() {
        let mut samples = two_columns();
        // θL −20, θi −10: θh 0, the column's first point.
        samples[0].dropped = [false, true, false];
        samples.push(Sample::in_plane(-20.0, 5.0, -25.0, [17.0, 12.0, 3.0]));
        let mut all_dropped = Sample::in_plane(-20.0, 7.0, -27.0, [1.0; 3]);
        all_dropped.dropped = [true; 3];
        samples.push(all_dropped);
        let table = Table::new(&samples, 0.0).unwrap();
        let column = &table.columns()[0];
        assert_eq!(column.points.len(), 4);
        assert_eq!(column.points[0][1], 0.0);
        assert!(column.points[0][2].is_nan() && column.points[0][3] == 1.0);
        assert_eq!(column.points[3][1..], [16.0, 11.0, 2.0]);
        assert_eq!(table.values(), 3 * 8 - 1);
        // Green at θh 0 comes from the column's known green around it (θh 5: 10) alone.
        assert_eq!(table.predict(0.0, 10.0, None)[1], 10.0);
        // It survives its JSON, the missing value a null.
        let json = serde_json::to_string(&table).unwrap();
        assert!(json.contains("null"), "{json}");
        let back: Table = serde_json::from_str(&json).unwrap();
        assert!(back.columns()[0].points[0][2].is_nan());
        assert_eq!(back.values(), table.values());
    }

    #[test]
    fn relative_to_a_shape_it_keeps_the_model_between_and_beyond_its_points() {
        // Samples of a Cook–Torrance lobe at θL −20 and −40, every 2° of θi (θh steps of
        // 2°, wider than the lobe): relative to the same model the table reproduces it
        // everywhere, between points, between columns and beyond both.
        let shape = Shape {
            model: Model::CookTorrance,
            params: Params::shared([5.0, 4.0, 3.0], [40.0, 30.0, 20.0], 0.02),
            ks_90: [40.0, 30.0, 20.0],
        };
        let mut samples = Vec::new();
        for theta_l in [-20.0, -40.0] {
            for k in 0..=10 {
                let theta_i = -15.0 + 3.0 * f64::from(k) + 0.37;
                let theta_r = theta_l - theta_i;
                let (h, d) =
                    half_difference(&Cosines::in_plane(theta_i, theta_r), theta_i >= theta_r);
                samples.push(Sample::in_plane(theta_l, theta_i, theta_r, shape.at(h, d)));
            }
        }
        let table = Table::new(&samples, 0.0).unwrap();
        for (h, d) in [
            (0.0, 10.0),
            (0.0, 15.0),
            (0.4, 18.0),
            (-30.0, 5.0),
            (25.0, 40.0),
        ] {
            let (got, want) = (table.predict(h, d, Some(&shape)), shape.at(h, d));
            for c in 0..3 {
                assert!(
                    (got[c] / want[c] - 1.0).abs() < 1e-9,
                    "{h} {d}: {got:?} {want:?}"
                );
            }
        }
        // Without the shape the peak between two points 3° apart is flattened.
        let flat = table.predict(0.0, 10.0, None);
        assert!(flat[0] < 0.5 * shape.at(0.0, 10.0)[0], "{flat:?}");
        // Scaled: a table of twice the model predicts twice it beyond its points.
        let doubled: Vec<Sample> = samples
            .iter()
            .map(|s| Sample {
                rgb: s.rgb.map(|v| 2.0 * v),
                ..*s
            })
            .collect();
        let table = Table::new(&doubled, 0.0).unwrap();
        let (got, want) = (
            table.predict(30.0, 30.0, Some(&shape)),
            shape.at(30.0, 30.0),
        );
        assert!((got[1] / want[1] - 2.0).abs() < 1e-9, "{got:?} {want:?}");
    }

    #[test]
    fn the_chromaticity_is_averaged_over_the_window_and_the_brightness_kept() {
        let points = vec![
            [0.0, 1.0, 2.0, 3.0],
            [1.0, 3.0, 2.0, 1.0],
            [5.0, 10.0, 10.0, 10.0],
        ];
        let smooth = smooth_chromaticity(points.clone(), 1.0);
        // The first two share their colour (sum 4, 4, 4), each keeps its own sum 6.
        assert_eq!(smooth[0], [0.0, 2.0, 2.0, 2.0]);
        assert_eq!(smooth[1], [1.0, 2.0, 2.0, 2.0]);
        assert_eq!(smooth[2], points[2]);
        assert_eq!(smooth_chromaticity(points.clone(), 0.0), points);
    }

    #[test]
    fn a_hostile_table_is_refused_before_it_is_used() {
        let table = Table::new(&two_columns(), 1.0).unwrap();
        let json = serde_json::to_value(&table).unwrap();
        let back: Table = serde_json::from_value(json.clone()).unwrap();
        assert_eq!(back, table);
        let refused = |edit: &dyn Fn(&mut serde_json::Value)| {
            let mut v = json.clone();
            edit(&mut v);
            serde_json::from_value::<Table>(v).unwrap_err().to_string()
        };
        let unsorted = refused(&|v| v["columns"][0]["points"][1][0] = (-1e9).into());
        assert!(unsorted.contains("strictly increasing"), "{unsorted}");
        let empty = refused(&|v| v["columns"] = serde_json::json!([]));
        assert!(empty.contains("empty"), "{empty}");
        let long = refused(&|v| {
            v["columns"][0]["points"] =
                serde_json::json!(vec![[0.0, 1.0, 1.0, 1.0]; MAX_POINTS_PER_COLUMN + 1])
        });
        assert!(long.contains("more than"), "{long}");
        let no_d = refused(&|v| v["columns"][1]["theta_d"] = 0.0.into());
        let window = refused(&|v| v["chromaticity_window"] = (-1.0).into());
        assert!(window.contains("window"), "{window}");
        assert!(no_d.contains("θd"), "{no_d}");
        // JSON has no infinity: an overflowing number is refused by the parser itself.
        let text = serde_json::to_string(&json)
            .unwrap()
            .replacen("10.0", "1e999", 1);
        assert!(serde_json::from_str::<Table>(&text).is_err());
    }
}
