//! The white reference's angular dependence: its reflectance factor against the angle
//! of incidence θi of the light on it, relative to its `white_reflectance` (taken as the
//! value at normal incidence).
//!
//! A real white is not Lambertian: it turns darker toward grazing incidence. setup.json
//! may state it as a certificate's table (`white_angular`: `theta_i_deg`, `factor` and the
//! factor's standard uncertainty `u` at each angle, linear in between, held beyond the
//! ends), else as a falloff a (`white_falloff`): the factor 1 − a·(1 − cos θi), 1 at
//! normal incidence and 1 − a at grazing. Without either the falloff is
//! [`DEFAULT_FALLOFF`] with the standard uncertainty [`DEFAULT_FALLOFF_UNCERTAINTY`] (or
//! the `uncertainty` block's `white_falloff`): a Lambertian white (a = 0) and one 3 %
//! darker at grazing (a = 0.03) both lie one standard uncertainty from it.
//! Extraction divides the white's reading by the factor at each column's white pixels.

use serde::{Deserialize, Serialize};

/// The default falloff toward grazing (relative): halfway between a Lambertian white and
/// one 3 % darker at grazing.
pub const DEFAULT_FALLOFF: f64 = 0.015;

/// The default falloff's standard uncertainty (relative).
pub const DEFAULT_FALLOFF_UNCERTAINTY: f64 = 0.015;

/// Largest |falloff| setup.json may state: the factor stays within [0.5, 1.5].
pub const MAX_FALLOFF: f64 = 0.5;

/// Largest number of rows a certificate's table may have.
pub const MAX_TABLE_ROWS: usize = 181;

/// setup.json's `white_angular`: a certificate's reflectance factor against the angle of
/// incidence, with its standard uncertainty (k = 1), one row per angle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WhiteTable {
    /// Angles of incidence, degrees, ascending within [0, 90].
    pub theta_i_deg: Vec<f64>,
    /// The factor at each angle, relative to `white_reflectance`, in (0, 2].
    pub factor: Vec<f64>,
    /// The factor's standard uncertainty at each angle, in [0, 1]; one error common to
    /// every angle (a certificate's errors are of one calibration).
    pub u: Vec<f64>,
}

/// Why a stated angular dependence cannot be used: the setup.json field and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("setup field `{field}`: {reason}")]
pub struct WhiteAngularError {
    pub field: &'static str,
    pub reason: String,
}

fn error(field: &'static str, reason: impl Into<String>) -> WhiteAngularError {
    WhiteAngularError {
        field,
        reason: reason.into(),
    }
}

impl WhiteTable {
    /// Checks the table: 1 to [`MAX_TABLE_ROWS`] rows of equal length, angles strictly
    /// ascending within [0, 90], factors in (0, 2], uncertainties in [0, 1].
    pub fn validate(&self) -> Result<(), WhiteAngularError> {
        let n = self.theta_i_deg.len();
        if !(1..=MAX_TABLE_ROWS).contains(&n) {
            return Err(error(
                "white_angular.theta_i_deg",
                format!("has {n} angles, 1 to {MAX_TABLE_ROWS} allowed"),
            ));
        }
        for (field, len) in [
            ("white_angular.factor", self.factor.len()),
            ("white_angular.u", self.u.len()),
        ] {
            if len != n {
                return Err(error(field, format!("has {len} values for {n} angles")));
            }
        }
        if let Some(t) = self
            .theta_i_deg
            .iter()
            .find(|t| !(t.is_finite() && (0.0..=90.0).contains(*t)))
        {
            return Err(error(
                "white_angular.theta_i_deg",
                format!("{t} is not an angle in [0, 90]"),
            ));
        }
        if self.theta_i_deg.windows(2).any(|w| w[1] <= w[0]) {
            return Err(error(
                "white_angular.theta_i_deg",
                "must be strictly ascending",
            ));
        }
        if let Some(f) = self
            .factor
            .iter()
            .find(|f| !(f.is_finite() && **f > 0.0 && **f <= 2.0))
        {
            return Err(error(
                "white_angular.factor",
                format!("{f} is not a factor in (0, 2]"),
            ));
        }
        if let Some(u) = self
            .u
            .iter()
            .find(|u| !(u.is_finite() && (0.0..=1.0).contains(*u)))
        {
            return Err(error(
                "white_angular.u",
                format!("{u} is not a standard uncertainty in [0, 1]"),
            ));
        }
        Ok(())
    }

    /// The factor and its standard uncertainty at `theta_deg`, linear between rows.
    fn at(&self, theta_deg: f64) -> (f64, f64) {
        let t = &self.theta_i_deg;
        let k = t.partition_point(|&x| x <= theta_deg);
        if k == 0 {
            return (self.factor[0], self.u[0]);
        }
        if k == t.len() {
            return (self.factor[k - 1], self.u[k - 1]);
        }
        let span = t[k] - t[k - 1];
        let w = if span > 0.0 {
            ((theta_deg - t[k - 1]) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let mix = |v: &[f64]| v[k - 1] + w * (v[k] - v[k - 1]);
        (mix(&self.factor), mix(&self.u))
    }
}

/// The white's angular dependence as extraction uses it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WhiteAngular<'a> {
    /// Factor 1 − a·(1 − cos θi), a known to a standard uncertainty `u`.
    Falloff { a: f64, u: f64 },
    /// A certificate's table.
    Table(&'a WhiteTable),
}

impl WhiteAngular<'_> {
    /// The factor at the cosine of the angle of incidence `cos_i` (clamped to [0, 1]) and
    /// the change of the factor for +1 standard uncertainty of the source.
    pub fn at(&self, cos_i: f64) -> (f64, f64) {
        let c = if cos_i.is_finite() {
            cos_i.clamp(0.0, 1.0)
        } else {
            1.0
        };
        match self {
            WhiteAngular::Falloff { a, u } => (1.0 - a * (1.0 - c), u * (1.0 - c)),
            WhiteAngular::Table(table) => table.at(c.acos().to_degrees()),
        }
    }

    /// The source's standard uncertainty at grazing, for the budget's inputs.
    pub fn grazing_uncertainty(&self) -> f64 {
        self.at(0.0).1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn falloff_and_table_give_factor_and_change() {
        let falloff = WhiteAngular::Falloff { a: 0.03, u: 0.01 };
        assert_eq!(falloff.at(1.0), (1.0, 0.0));
        let (f, u) = falloff.at(0.5);
        assert!((f - 0.985).abs() < 1e-12 && (u - 0.005).abs() < 1e-12);
        assert_eq!(falloff.at(f64::NAN), (1.0, 0.0));
        let table = WhiteTable {
            theta_i_deg: vec![0.0, 60.0, 80.0],
            factor: vec![1.0, 0.98, 0.95],
            u: vec![0.0, 0.01, 0.02],
        };
        table.validate().unwrap();
        let angular = WhiteAngular::Table(&table);
        let (f, u) = angular.at(0.5);
        assert!(
            (f - 0.98).abs() < 1e-9 && (u - 0.01).abs() < 1e-9,
            "{f} {u}"
        );
        let (f, _) = angular.at(70f64.to_radians().cos());
        assert!((f - 0.965).abs() < 1e-9, "{f}");
        assert_eq!(angular.at(0.0), (0.95, 0.02));
        assert_eq!(angular.grazing_uncertainty(), 0.02);
    }

    #[test]
    fn bad_tables_name_the_field() {
        let good = WhiteTable {
            theta_i_deg: vec![0.0, 45.0],
            factor: vec![1.0, 0.99],
            u: vec![0.0, 0.01],
        };
        let cases = [
            (
                WhiteTable {
                    factor: vec![1.0],
                    ..good.clone()
                },
                "white_angular.factor",
            ),
            (
                WhiteTable {
                    theta_i_deg: vec![45.0, 0.0],
                    ..good.clone()
                },
                "white_angular.theta_i_deg",
            ),
            (
                WhiteTable {
                    theta_i_deg: vec![0.0, 95.0],
                    ..good.clone()
                },
                "white_angular.theta_i_deg",
            ),
            (
                WhiteTable {
                    factor: vec![1.0, 0.0],
                    ..good.clone()
                },
                "white_angular.factor",
            ),
            (
                WhiteTable {
                    u: vec![0.0, f64::NAN],
                    ..good.clone()
                },
                "white_angular.u",
            ),
            (
                WhiteTable {
                    theta_i_deg: vec![],
                    factor: vec![],
                    u: vec![],
                },
                "white_angular.theta_i_deg",
            ),
        ];
        for (table, field) in cases {
            let err = table.validate().unwrap_err();
            assert_eq!(err.field, field, "{err}");
            assert!(err.to_string().contains(field));
        }
    }
}
