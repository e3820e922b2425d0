//! Goniospectrophotometer reference data: spectral radiance factors on a (θi, θr) grid,
//! converted to camera RGB (paper eq. 5) and interpolated at any (θi, θr).
//!
//! CSV: header `theta_i,theta_r,` then one column per wavelength in nm (e.g.
//! `390,400,...,730`); angles in degrees. The wavelengths must include 400–700 nm at
//! 10 nm (the eq. 5 sum); others are ignored.
//!
//! Interpolation is a tensor-product natural cubic spline: along θr within each row of
//! equal θi (through that row's own nodes, so a missing node is simply bridged), then
//! along θi through the rows whose θr span covers the point. Rows with two nodes are
//! linear. Outside the grid there is no extrapolation: the result is `None`.

use std::io::Read;
use std::path::{Path, PathBuf};

use thiserror::Error;

use crate::color::{CameraModel, ColorError};

/// Errors reading reference data.
#[derive(Debug, Error)]
pub enum ReferenceError {
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("{name}: line {line}: {reason}")]
    Parse {
        name: String,
        line: usize,
        reason: String,
    },
    #[error("{name}: {error}")]
    Color { name: String, error: ColorError },
    #[error("{name}: no rows")]
    Empty { name: String },
}

/// One grid node in camera RGB.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferencePoint {
    pub theta_i: f64,
    pub theta_r: f64,
    pub rgb: [f64; 3],
}

/// Natural cubic spline through (x, y) nodes with x strictly ascending.
#[derive(Debug, Clone, PartialEq)]
struct Spline {
    x: Vec<f64>,
    y: Vec<[f64; 3]>,
    /// Second derivatives at the nodes.
    m: Vec<[f64; 3]>,
}

impl Spline {
    fn new(x: Vec<f64>, y: Vec<[f64; 3]>) -> Self {
        let n = x.len();
        let mut m = vec![[0.0; 3]; n];
        if n >= 3 {
            // Tridiagonal system for the interior second derivatives (Thomas algorithm).
            let mut diag = vec![0.0; n];
            let mut rhs = vec![[0.0; 3]; n];
            let mut upper = vec![0.0; n];
            for i in 1..n - 1 {
                let (h0, h1) = (x[i] - x[i - 1], x[i + 1] - x[i]);
                diag[i] = 2.0 * (h0 + h1);
                upper[i] = h1;
                rhs[i] = [0, 1, 2]
                    .map(|c| 6.0 * ((y[i + 1][c] - y[i][c]) / h1 - (y[i][c] - y[i - 1][c]) / h0));
            }
            for i in 2..n - 1 {
                let factor = (x[i] - x[i - 1]) / diag[i - 1];
                diag[i] -= factor * upper[i - 1];
                let previous = rhs[i - 1];
                for (r, p) in rhs[i].iter_mut().zip(previous) {
                    *r -= factor * p;
                }
            }
            for i in (1..n - 1).rev() {
                let next = m[i + 1];
                m[i] = [0, 1, 2].map(|c| (rhs[i][c] - upper[i] * next[c]) / diag[i]);
            }
        }
        Self { x, y, m }
    }

    fn covers(&self, t: f64) -> bool {
        self.x.len() >= 2 && t >= self.x[0] - 1e-9 && t <= self.x[self.x.len() - 1] + 1e-9
    }

    /// Value at t, which must lie within the nodes.
    fn eval(&self, t: f64) -> [f64; 3] {
        let n = self.x.len();
        let k = self.x.partition_point(|&v| v <= t).clamp(1, n - 1);
        let (x0, x1) = (self.x[k - 1], self.x[k]);
        let h = x1 - x0;
        let (a, b) = ((x1 - t) / h, (t - x0) / h);
        let mut out = [0.0; 3];
        for (c, value) in out.iter_mut().enumerate() {
            *value = a * self.y[k - 1][c]
                + b * self.y[k][c]
                + ((a * a * a - a) * self.m[k - 1][c] + (b * b * b - b) * self.m[k][c]) * h * h
                    / 6.0;
        }
        out
    }
}

/// Reference measurements in camera RGB, ready for interpolation.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    points: Vec<ReferencePoint>,
    /// Splines along θr, one per distinct θi (ascending).
    rows: Vec<(f64, Spline)>,
}

/// Largest reference CSV read (a goniospectrophotometer's grid takes a few megabytes).
const MAX_CSV_BYTES: u64 = 256 << 20;

impl Reference {
    /// Reads a reference CSV and converts it with the built-in camera model.
    pub fn read_csv(path: &Path) -> Result<Self, ReferenceError> {
        let file = gonio_files::input::open_input(path, MAX_CSV_BYTES).map_err(|error| {
            ReferenceError::Io {
                path: path.to_path_buf(),
                error,
            }
        })?;
        Self::from_reader(file, &path.display().to_string(), &CameraModel::builtin())
    }

    /// Reads a reference CSV from `reader` (`name` appears in errors).
    pub fn from_reader<R: Read>(
        reader: R,
        name: &str,
        camera: &CameraModel,
    ) -> Result<Self, ReferenceError> {
        let parse_err = |line: usize, reason: String| ReferenceError::Parse {
            name: name.to_string(),
            line,
            reason,
        };
        let mut csv = csv::ReaderBuilder::new()
            .has_headers(false)
            .trim(csv::Trim::All)
            .from_reader(reader);
        let mut records = csv.records();
        let header = records
            .next()
            .ok_or_else(|| ReferenceError::Empty {
                name: name.to_string(),
            })?
            .map_err(|e| parse_err(1, e.to_string()))?;
        if header.get(0) != Some("theta_i") || header.get(1) != Some("theta_r") {
            return Err(parse_err(
                1,
                "header must start with theta_i,theta_r".into(),
            ));
        }
        let wavelengths: Vec<f64> = header
            .iter()
            .skip(2)
            .map(|h| {
                h.parse::<f64>()
                    .map_err(|_| parse_err(1, format!("column '{h}' is not a wavelength in nm")))
            })
            .collect::<Result<_, _>>()?;
        let columns: Vec<usize> = camera
            .wavelengths_nm()
            .iter()
            .map(|&w| {
                wavelengths
                    .iter()
                    .position(|&x| (x - w).abs() < 1e-6)
                    .map(|p| p + 2)
                    .ok_or_else(|| parse_err(1, format!("no column for {w} nm")))
            })
            .collect::<Result<_, _>>()?;
        let mut points = Vec::new();
        let mut spectrum = vec![0.0; columns.len()];
        for (index, record) in records.enumerate() {
            let line = index + 2;
            let record = record.map_err(|e| parse_err(line, e.to_string()))?;
            if record.len() != header.len() {
                return Err(parse_err(
                    line,
                    format!("{} fields, header has {}", record.len(), header.len()),
                ));
            }
            let field = |i: usize| -> Result<f64, ReferenceError> {
                let text = record.get(i).unwrap_or("");
                text.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| {
                        parse_err(
                            line,
                            format!(
                                "{}: '{text}' is not a finite number",
                                header.get(i).unwrap_or("?")
                            ),
                        )
                    })
            };
            let (theta_i, theta_r) = (field(0)?, field(1)?);
            if theta_i.abs() > 90.0 || theta_r.abs() > 90.0 {
                return Err(parse_err(
                    line,
                    "angles must lie in [-90, 90] degrees".into(),
                ));
            }
            for (slot, &col) in spectrum.iter_mut().zip(&columns) {
                *slot = field(col)?;
            }
            let rgb = camera
                .camera_rgb(&spectrum)
                .map_err(|error| ReferenceError::Color {
                    name: name.to_string(),
                    error,
                })?;
            // The spline and the metrics square β: values that overflow are refused.
            if rgb.iter().any(|v| !(v * v * 1e6).is_finite()) {
                return Err(parse_err(
                    line,
                    "spectral values too large: their camera RGB overflows".into(),
                ));
            }
            points.push(ReferencePoint {
                theta_i,
                theta_r,
                rgb,
            });
        }
        if points.is_empty() {
            return Err(ReferenceError::Empty {
                name: name.to_string(),
            });
        }
        Self::from_points(points).map_err(|(line, reason)| parse_err(line, reason))
    }

    /// Builds the interpolator from camera-RGB nodes. Errors name the 1-based data
    /// row (plus one for a header) of a duplicate node.
    fn from_points(points: Vec<ReferencePoint>) -> Result<Self, (usize, String)> {
        let mut order: Vec<usize> = (0..points.len()).collect();
        // Angles are finite; −0 and 0 are one angle (a total order would split them
        // and leave a row's θr unsorted).
        let angle = |a: f64, b: f64| a.partial_cmp(&b).unwrap_or(std::cmp::Ordering::Equal);
        order.sort_by(|&a, &b| {
            angle(points[a].theta_i, points[b].theta_i)
                .then(angle(points[a].theta_r, points[b].theta_r))
        });
        let mut rows: Vec<(f64, Spline)> = Vec::new();
        let mut start = 0;
        while start < order.len() {
            let theta_i = points[order[start]].theta_i;
            let end = start
                + order[start..]
                    .iter()
                    .take_while(|&&k| points[k].theta_i == theta_i)
                    .count();
            let nodes = &order[start..end];
            for pair in nodes.windows(2) {
                if points[pair[0]].theta_r == points[pair[1]].theta_r {
                    return Err((
                        pair[1] + 2,
                        format!(
                            "duplicate node θi {theta_i}, θr {}",
                            points[pair[1]].theta_r
                        ),
                    ));
                }
            }
            let x = nodes.iter().map(|&k| points[k].theta_r).collect();
            let y = nodes.iter().map(|&k| points[k].rgb).collect();
            rows.push((theta_i, Spline::new(x, y)));
            start = end;
        }
        Ok(Self { points, rows })
    }

    /// The grid nodes in camera RGB (eq. 5), in file order.
    pub fn points(&self) -> &[ReferencePoint] {
        &self.points
    }

    /// Camera RGB at (θi, θr) in degrees by piecewise cubic splines; `None` outside the
    /// grid (no row pair brackets θi, or fewer than two rows around it cover θr).
    pub fn interpolate(&self, theta_i: f64, theta_r: f64) -> Option<[f64; 3]> {
        if !(theta_i.is_finite() && theta_r.is_finite()) {
            return None;
        }
        let (x, y): (Vec<f64>, Vec<[f64; 3]>) = self
            .rows
            .iter()
            .filter(|(_, row)| row.covers(theta_r))
            .map(|(ti, row)| (*ti, row.eval(theta_r)))
            .unzip();
        if let Some(k) = x.iter().position(|&v| (v - theta_i).abs() < 1e-9) {
            return Some(y[k]);
        }
        let column = Spline::new(x, y);
        column.covers(theta_i).then(|| column.eval(theta_i))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn natural_spline_reproduces_nodes_and_lines() {
        let x = vec![0.0, 1.0, 3.0, 4.0];
        let y: Vec<[f64; 3]> = x.iter().map(|&v| [2.0 * v + 1.0, -v, 5.0]).collect();
        let s = Spline::new(x.clone(), y.clone());
        for (xi, yi) in x.iter().zip(&y) {
            assert_eq!(s.eval(*xi), *yi);
        }
        let v = s.eval(2.2);
        assert!(
            (v[0] - 5.4).abs() < 1e-12 && (v[1] + 2.2).abs() < 1e-12 && (v[2] - 5.0).abs() < 1e-12
        );
    }

    /// −0 and 0 are one angle: a node given under both is a duplicate.
    #[test]
    fn signed_zeros_are_one_angle() {
        let camera = CameraModel::builtin();
        let wavelengths: Vec<String> = (390..=730).step_by(10).map(|w| w.to_string()).collect();
        let csv = |rows: &[(&str, &str, f64)]| {
            let mut text = format!("theta_i,theta_r,{}\n", wavelengths.join(","));
            for (ti, tr, v) in rows {
                let values = vec![v.to_string(); wavelengths.len()].join(",");
                text += &format!("{ti},{tr},{values}\n");
            }
            text
        };
        // Sorted with −0 before 0, the row θi = 0 would read θr 0, 10, 0: its
        // duplicate node missed, its spline unsorted.
        let dup = csv(&[
            ("-10", "-10", 0.5),
            ("-0", "0", 0.5),
            ("-0", "10", 0.5),
            ("0", "0", 0.5),
            ("10", "10", 0.5),
        ]);
        let err = Reference::from_reader(dup.as_bytes(), "dup", &camera).unwrap_err();
        assert!(err.to_string().contains("duplicate node"), "{err}");
    }
}
