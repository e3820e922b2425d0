//! RGL-EPFL measured materials (Dupuy & Jakob 2018, *An Adaptive Parameterization for
//! Efficient Material Acquisition and Rendering*): the `.bsdf` tensor file, read with
//! every size checked against the file before anything is allocated, and its
//! evaluation as the authors' reference evaluator (`powitacq`) evaluates it.
//!
//! A file holds, on the unit square of (u_θ, u_φ) = (√(2θ/π), (φ + π)/2π): the NDF and
//! the projected area σ(ωi); the visible NDF (VNDF) as a 2-D density conditional on the
//! incidence (φi, θi); and the measured values, three RGB channels or one slice per
//! wavelength, on the square the VNDF warps. The value at (ωi, ωo), unit vectors with z
//! the surface normal, is f_r·cos θo: ωm = (ωi + ωo)/|ωi + ωo|; (x, y) the inverse of the
//! VNDF warp at ωm's unit coordinates (azimuth φm − φi, the file being isotropic); the
//! values bilinear at (x, y) and linear in (φi, θi), RGB ones clipped at 0; times
//! NDF(ωm)/(4 σ(ωi)). Everything is evaluated in f64.

use std::collections::HashMap;
use std::f64::consts::PI;
use std::path::Path;

use super::error::SceneError;
use super::spectral::{self, CameraDomain, Spectrum, BANDS};

/// Largest `.bsdf` file read (RGL's isotropic files are a few MB); a scene may name any
/// path (even `/dev/zero`).
const MAX_BSDF_BYTES: u64 = 256 << 20;

/// Smallest cos θo by which f_r cos θo is divided (as the other models clamp cosines).
const MIN_COS: f64 = 1e-4;

/// Type codes of the tensor format used here.
const UINT8: u8 = 1;
const FLOAT32: u8 = 10;

/// Element size in bytes of tensor type codes 1–11 (u8, i8, u16, i16, u32, i32, u64,
/// i64, f16, f32, f64).
fn dtype_size(code: u8) -> Option<u64> {
    match code {
        1 | 2 => Some(1),
        3 | 4 | 9 => Some(2),
        5 | 6 | 10 => Some(4),
        7 | 8 | 11 => Some(8),
        _ => None,
    }
}

/// One named array of a tensor file: its type code, shape and bytes (inside the file).
struct Field<'a> {
    dtype: u8,
    shape: Vec<u64>,
    data: &'a [u8],
}

/// Reads little-endian values from the front of a byte slice, never past its end.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&end| end <= self.bytes.len())
            .ok_or_else(|| format!("truncated: {what} at byte {} runs past the end", self.pos))?;
        let out = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(out)
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], String> {
        Ok(self
            .take(N, what)?
            .try_into()
            .expect("take returns N bytes"))
    }
}

/// The fields of a tensor file, each checked to lie inside it.
fn parse_fields(bytes: &[u8]) -> Result<HashMap<String, Field<'_>>, String> {
    let mut cursor = Cursor { bytes, pos: 0 };
    if cursor.take(12, "the header").ok() != Some(b"tensor_file\0".as_slice()) {
        return Err("not a tensor file (no `tensor_file` header)".into());
    }
    let [major, minor] = cursor.array::<2>("the version")?;
    if (major, minor) != (1, 0) {
        return Err(format!("tensor file version {major}.{minor}, expected 1.0"));
    }
    let count = u32::from_le_bytes(cursor.array("the field count")?);
    let mut fields = HashMap::new();
    for _ in 0..count {
        let name_len = u16::from_le_bytes(cursor.array("a field's name length")?);
        // Escaped, so that an error quoting it stays on one line.
        let name = String::from_utf8_lossy(cursor.take(name_len.into(), "a field's name")?)
            .escape_debug()
            .to_string();
        let rank = u16::from_le_bytes(cursor.array("a field's rank")?);
        let [dtype] = cursor.array::<1>("a field's type")?;
        let offset = u64::from_le_bytes(cursor.array("a field's offset")?);
        let element = dtype_size(dtype)
            .ok_or_else(|| format!("field `{name}`: unknown type code {dtype}"))?;
        let dims = cursor.take(usize::from(rank) * 8, "a field's shape")?;
        let shape: Vec<u64> = dims
            .chunks_exact(8)
            .map(|d| u64::from_le_bytes(d.try_into().expect("8-byte chunk")))
            .collect();
        let end = shape
            .iter()
            .try_fold(element, |size, &d| size.checked_mul(d))
            .and_then(|size| offset.checked_add(size))
            .filter(|&end| end <= bytes.len() as u64)
            .ok_or_else(|| {
                format!(
                    "field `{name}` of shape {shape:?} at byte {offset} runs past the end of \
                     the file ({} bytes)",
                    bytes.len()
                )
            })?;
        // Both bounds are at most the file's length, so they fit a usize.
        let data = &bytes[offset as usize..end as usize];
        fields.insert(name, Field { dtype, shape, data });
    }
    Ok(fields)
}

/// The fields of one file, looked up by name with their type and rank checked.
struct Fields<'a>(HashMap<String, Field<'a>>);

impl Fields<'_> {
    /// Field `name`, checked to be of type `dtype` and rank `rank`.
    fn typed(&self, name: &str, dtype: u8, rank: usize) -> Result<&Field<'_>, String> {
        let field = self
            .0
            .get(name)
            .ok_or_else(|| format!("no field `{name}`"))?;
        if field.dtype != dtype || field.shape.len() != rank {
            return Err(format!(
                "field `{name}` is type {} of rank {}, expected type {dtype} of rank {rank}",
                field.dtype,
                field.shape.len()
            ));
        }
        Ok(field)
    }

    /// The shape of field `name`, of type `dtype` and rank `rank`, every extent ≥ 1.
    fn shape(&self, name: &str, dtype: u8, rank: usize) -> Result<Vec<usize>, String> {
        let field = self.typed(name, dtype, rank)?;
        if field.shape.contains(&0) {
            return Err(format!("field `{name}` has an empty extent"));
        }
        // Every extent is ≥ 1 and their product fits in the file.
        Ok(field.shape.iter().map(|&d| d as usize).collect())
    }

    /// The values of float32 field `name` (its shape checked by [`Fields::shape`]),
    /// each finite.
    fn floats(&self, name: &str) -> Result<Vec<f64>, String> {
        let data = self.0[name].data;
        let values: Vec<f64> = data
            .chunks_exact(4)
            .map(|b| f64::from(f32::from_le_bytes(b.try_into().expect("4-byte chunk"))))
            .collect();
        match values.iter().position(|v| !v.is_finite()) {
            Some(k) => Err(format!("field `{name}`: value {k} is not finite")),
            None => Ok(values),
        }
    }

    fn has(&self, name: &str) -> bool {
        self.0.contains_key(name)
    }
}

/// Checks that the values of `name` increase strictly (an interpolation axis).
fn increasing(name: &str, values: &[f64]) -> Result<(), String> {
    if values.windows(2).all(|w| w[0] < w[1]) {
        Ok(())
    } else {
        Err(format!("field `{name}` does not increase strictly"))
    }
}

/// The grid cell of `u` ∈ [0, 1] on `n` ≥ 2 evenly spaced nodes: the cell's first node
/// and the offset in it, in cells (the last cell extends beyond 1, the first below 0).
fn cell(u: f64, n: usize) -> (usize, f64) {
    let x = u * (n - 1) as f64;
    // `as` saturates: a value just below 0 (rounding) lands in the first cell.
    let k = (x as usize).min(n - 2);
    (k, x - k as f64)
}

/// A parameter axis of the tables (φi or θi, radians): the nodes the slices sit at.
#[derive(Debug, Clone, PartialEq)]
struct Axis(Vec<f64>);

impl Axis {
    /// The two nodes around `p` and their linear weights, `p` clamped to the axis (one
    /// node: that node twice).
    fn weights(&self, p: f64) -> [(usize, f64); 2] {
        let v = &self.0;
        if v.len() == 1 {
            return [(0, 1.0), (0, 0.0)];
        }
        let below = v[..v.len() - 1].partition_point(|x| *x <= p);
        let k = below.saturating_sub(1);
        let t = ((p - v[k]) / (v[k + 1] - v[k])).clamp(0.0, 1.0);
        [(k, 1.0 - t), (k + 1, t)]
    }
}

/// Slices (index into φi × θi, row-major) and weights of a lookup at (φi, θi).
type Corners = [(usize, f64); 4];

/// A 2-D table on the unit square, `nx` × `ny` nodes, per slice (row-major: slice,
/// then y, then x).
#[derive(Debug, Clone, PartialEq)]
struct Grid {
    nx: usize,
    ny: usize,
    data: Vec<f64>,
}

impl Grid {
    fn slice_len(&self) -> usize {
        self.nx * self.ny
    }

    /// Bilinear value of slice `slice` at `u` = (x, y).
    fn at(&self, slice: usize, u: [f64; 2]) -> f64 {
        let (kx, tx) = cell(u[0], self.nx);
        let (ky, ty) = cell(u[1], self.ny);
        let d = &self.data[slice * self.slice_len()..];
        let i = kx + ky * self.nx;
        let row = |j: usize| (1.0 - tx) * d[j] + tx * d[j + 1];
        (1.0 - ty) * row(i) + ty * row(i + self.nx)
    }
}

/// The VNDF warp: per (φi, θi) slice, the density normalised to unit mass, the
/// conditional CDF along x of each row and the marginal CDF over rows, built by the
/// trapezoid rule on the nodes as the reference does.
#[derive(Debug, Clone, PartialEq)]
struct Warp {
    density: Grid,
    conditional: Vec<f64>,
    marginal: Vec<f64>,
}

impl Warp {
    fn new(density: Grid, slices: usize) -> Result<Self, String> {
        let (nx, ny, n) = (density.nx, density.ny, density.slice_len());
        if let Some(v) = density.data.iter().find(|v| **v < 0.0) {
            return Err(format!("field `vndf` holds a negative density {v}"));
        }
        let mut data = density.data;
        let mut conditional = vec![0.0; data.len()];
        let mut marginal = vec![0.0; slices * ny];
        for s in 0..slices {
            let (d, c) = (
                &mut data[s * n..(s + 1) * n],
                &mut conditional[s * n..(s + 1) * n],
            );
            let m = &mut marginal[s * ny..(s + 1) * ny];
            for y in 0..ny {
                let i = y * nx;
                for x in 0..nx - 1 {
                    c[i + x + 1] = c[i + x] + 0.5 * (d[i + x] + d[i + x + 1]);
                }
            }
            for y in 0..ny - 1 {
                m[y + 1] = m[y] + 0.5 * (c[(y + 1) * nx - 1] + c[(y + 2) * nx - 1]);
            }
            let total = m[ny - 1];
            if !(total > 0.0 && total.is_finite()) {
                return Err(format!("field `vndf`: slice {s} has no mass"));
            }
            for v in d.iter_mut().chain(c.iter_mut()).chain(m.iter_mut()) {
                *v /= total;
            }
        }
        Ok(Self {
            density: Grid { nx, ny, data },
            conditional,
            marginal,
        })
    }

    /// The point of the unit square the warp maps to `u` (its inverse), the slices
    /// interpolated with `corners`.
    fn invert(&self, u: [f64; 2], corners: &Corners) -> [f64; 2] {
        let (nx, ny, n) = (self.density.nx, self.density.ny, self.density.slice_len());
        let at = |table: &[f64], len: usize, i: usize| -> f64 {
            corners.iter().map(|(s, w)| w * table[s * len + i]).sum()
        };
        let (kx, mut sx) = cell(u[0], nx);
        let (ky, mut sy) = cell(u[1], ny);
        let offset = kx + ky * nx;
        let d = &self.density.data;
        let (v00, v10) = (at(d, n, offset), at(d, n, offset + 1));
        let (v01, v11) = (at(d, n, offset + nx), at(d, n, offset + nx + 1));
        let c0 = (1.0 - sy) * v00 + sy * v01;
        let c1 = (1.0 - sy) * v10 + sy * v11;
        sx *= c0 + 0.5 * sx * (c1 - c0);
        let c = &self.conditional;
        sx += (1.0 - sy) * at(c, n, offset) + sy * at(c, n, offset + nx);
        let r0 = at(c, n, ky * nx + nx - 1);
        let r1 = at(c, n, ky * nx + 2 * nx - 1);
        let row_mass = (1.0 - sy) * r0 + sy * r1;
        // A row pair without mass (the reference divides 0 by 0 there): its start.
        sx = if row_mass > 0.0 { sx / row_mass } else { 0.0 };
        sy *= r0 + 0.5 * sy * (r1 - r0);
        sy += at(&self.marginal, ny, ky);
        [sx, sy]
    }
}

/// What a file's values are.
#[derive(Debug, Clone, PartialEq)]
pub enum Kind {
    /// Linear sRGB channels (clipped at 0 when evaluated, as the reference does).
    Rgb,
    /// One channel per wavelength (nm, increasing).
    Spectral { wavelengths_nm: Vec<f64> },
}

/// The lookup of one direction pair: the slices, the point of the values' square and
/// the factor NDF(ωm)/(4 σ(ωi)).
struct Lookup {
    corners: Corners,
    point: [f64; 2],
    factor: f64,
}

/// Everything of a file but its values: the axes, NDF, σ and the VNDF warp.
#[derive(Debug, Clone, PartialEq)]
struct Geometry {
    phi_i: Axis,
    theta_i: Axis,
    ndf: Grid,
    sigma: Grid,
    vndf: Warp,
}

/// 2 asin(|d − z|/2), the polar angle of unit vector `d` (stable near the pole).
fn elevation(d: [f64; 3]) -> f64 {
    let half = 0.5 * (d[0] * d[0] + d[1] * d[1] + (d[2] - 1.0) * (d[2] - 1.0)).sqrt();
    2.0 * half.min(1.0).asin()
}

fn theta_to_u(theta: f64) -> f64 {
    (theta * (2.0 / PI)).sqrt()
}

fn phi_to_u(phi: f64) -> f64 {
    (phi + PI) / (2.0 * PI)
}

impl Geometry {
    fn lookup(&self, wi: [f64; 3], wo: [f64; 3]) -> Option<Lookup> {
        if !(wi[2] > 0.0 && wo[2] > 0.0) {
            return None;
        }
        let sum: [f64; 3] = std::array::from_fn(|k| wi[k] + wo[k]);
        let len = (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]).sqrt();
        let wm = sum.map(|x| x / len);
        let (theta_i, phi_i) = (elevation(wi), wi[1].atan2(wi[0]));
        let (theta_m, phi_m) = (elevation(wm), wm[1].atan2(wm[0]));
        let u_wi = [theta_to_u(theta_i), phi_to_u(phi_i)];
        let azimuth = phi_to_u(phi_m - phi_i);
        let u_wm = [theta_to_u(theta_m), azimuth - azimuth.floor()];
        let [(p0, wp0), (p1, wp1)] = self.phi_i.weights(phi_i);
        let [(t0, wt0), (t1, wt1)] = self.theta_i.weights(theta_i);
        let n = self.theta_i.0.len();
        let corners = [
            (p0 * n + t0, wp0 * wt0),
            (p0 * n + t1, wp0 * wt1),
            (p1 * n + t0, wp1 * wt0),
            (p1 * n + t1, wp1 * wt1),
        ];
        let point = self.vndf.invert(u_wm, &corners);
        let factor = self.ndf.at(0, u_wm) / (4.0 * self.sigma.at(0, u_wi));
        Some(Lookup {
            corners,
            point,
            factor,
        })
    }
}

/// Channel tables on the values' square: per (φi, θi) slice, `channels` grids.
#[derive(Debug, Clone, PartialEq)]
struct Channels {
    channels: usize,
    grid: Grid,
}

impl Channels {
    /// Channel `c` at a lookup, not yet scaled by its factor.
    fn at(&self, look: &Lookup, c: usize) -> f64 {
        look.corners
            .iter()
            .map(|(s, w)| w * self.grid.at(s * self.channels + c, look.point))
            .sum()
    }

    /// The tables of channels `map` · (these channels), node by node (`map` one row
    /// per new channel); interpolation is linear, so evaluating the new tables equals
    /// mapping the evaluated channels.
    fn mapped(&self, map: &[Vec<f64>]) -> Channels {
        let n = self.grid.slice_len();
        let slices = self.grid.data.len() / (n * self.channels);
        let mut data = vec![0.0; slices * map.len() * n];
        for s in 0..slices {
            let old = &self.grid.data[s * self.channels * n..(s + 1) * self.channels * n];
            for (c, row) in map.iter().enumerate() {
                let out = &mut data[(s * map.len() + c) * n..(s * map.len() + c + 1) * n];
                for (k, w) in row.iter().enumerate().filter(|(_, w)| **w != 0.0) {
                    for (o, v) in out.iter_mut().zip(&old[k * n..(k + 1) * n]) {
                        *o += w * v;
                    }
                }
            }
        }
        Channels {
            channels: map.len(),
            grid: Grid {
                nx: self.grid.nx,
                ny: self.grid.ny,
                data,
            },
        }
    }
}

/// A `.bsdf` file, evaluated as the reference evaluator evaluates it.
#[derive(Debug, Clone, PartialEq)]
pub struct RglBsdf {
    geometry: Geometry,
    values: Channels,
    kind: Kind,
}

impl RglBsdf {
    /// Reads a `.bsdf` file (at most 256 MiB); an anisotropic one is refused.
    pub fn read(path: &Path) -> Result<Self, SceneError> {
        let bytes = gonio_files::input::read_input(path, MAX_BSDF_BYTES).map_err(|error| {
            SceneError::Io {
                path: path.to_path_buf(),
                error,
            }
        })?;
        Self::from_bytes(&bytes).map_err(|reason| SceneError::Bsdf {
            path: path.to_path_buf(),
            reason,
        })
    }

    /// Parses the bytes of a `.bsdf` file; the error says what is wrong in one line.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, String> {
        let fields = Fields(parse_fields(bytes)?);
        let phi_n = fields.shape("phi_i", FLOAT32, 1)?[0];
        if phi_n > 2 {
            return Err(format!(
                "anisotropic material ({phi_n} φi slices): only isotropic files (at most 2) \
                 are rendered"
            ));
        }
        let theta_n = fields.shape("theta_i", FLOAT32, 1)?[0];
        fields.typed("description", UINT8, 1)?;
        if fields.shape("jacobian", UINT8, 1)? != [1] {
            return Err("field `jacobian` must hold one value".into());
        }
        let grid = |name: &str| -> Result<Grid, String> {
            let shape = fields.shape(name, FLOAT32, 2)?;
            Ok(Grid {
                nx: shape[1],
                ny: shape[0],
                data: fields.floats(name)?,
            })
        };
        let ndf = grid("ndf")?;
        let sigma = grid("sigma")?;
        let vndf = fields.shape("vndf", FLOAT32, 4)?;
        let luminance = fields.shape("luminance", FLOAT32, 4)?;
        let (values_name, kind) = if fields.has("rgb") {
            ("rgb", Kind::Rgb)
        } else if fields.has("spectra") {
            fields.shape("wavelengths", FLOAT32, 1)?;
            let wavelengths_nm = fields.floats("wavelengths")?;
            increasing("wavelengths", &wavelengths_nm)?;
            ("spectra", Kind::Spectral { wavelengths_nm })
        } else {
            return Err("no field `rgb` or `spectra`".into());
        };
        let values = fields.shape(values_name, FLOAT32, 5)?;
        let channels = match &kind {
            Kind::Rgb => 3,
            Kind::Spectral { wavelengths_nm } => wavelengths_nm.len(),
        };
        let structure = [
            (
                vndf[..2] == [phi_n, theta_n],
                "vndf's first extents are (φi, θi)",
            ),
            (
                luminance[..2] == [phi_n, theta_n],
                "luminance's first extents are (φi, θi)",
            ),
            (
                values[..3] == [phi_n, theta_n, channels],
                "the values' first extents are (φi, θi, channels)",
            ),
            (
                luminance[2..] == values[3..],
                "luminance and the values share one grid",
            ),
            (values[3] == values[4], "the values' grid is square"),
        ];
        if let Some((_, what)) = structure.iter().find(|(ok, _)| !ok) {
            return Err(format!("invalid structure: {what}"));
        }
        for (name, g) in [
            ("ndf", (ndf.nx, ndf.ny)),
            ("sigma", (sigma.nx, sigma.ny)),
            ("vndf", (vndf[3], vndf[2])),
            (values_name, (values[4], values[3])),
        ] {
            if g.0 < 2 || g.1 < 2 {
                return Err(format!("field `{name}`: a grid needs at least 2 × 2 nodes"));
            }
        }
        if let Some(v) = ndf.data.iter().find(|v| **v < 0.0) {
            return Err(format!("field `ndf` holds a negative value {v}"));
        }
        if let Some(v) = sigma.data.iter().find(|v| **v <= 0.0) {
            return Err(format!("field `sigma` holds a non-positive value {v}"));
        }
        let phi_i = fields.floats("phi_i")?;
        let theta_i = fields.floats("theta_i")?;
        increasing("phi_i", &phi_i)?;
        increasing("theta_i", &theta_i)?;
        let vndf = Warp::new(
            Grid {
                nx: vndf[3],
                ny: vndf[2],
                data: fields.floats("vndf")?,
            },
            phi_n * theta_n,
        )?;
        let values = Channels {
            channels,
            grid: Grid {
                nx: values[4],
                ny: values[3],
                data: fields.floats(values_name)?,
            },
        };
        Ok(Self {
            geometry: Geometry {
                phi_i: Axis(phi_i),
                theta_i: Axis(theta_i),
                ndf,
                sigma,
                vndf,
            },
            values,
            kind,
        })
    }

    /// What the values are.
    pub fn kind(&self) -> &Kind {
        &self.kind
    }

    /// f_r·cos θo per channel (RGB, or per wavelength of [`Kind::Spectral`]) for light
    /// from unit vector `wi` seen from unit vector `wo` (z the normal); 0 below the
    /// surface. The reference evaluator's `eval`.
    pub fn eval(&self, wi: [f64; 3], wo: [f64; 3]) -> Vec<f64> {
        let Some(look) = self.geometry.lookup(wi, wo) else {
            return vec![0.0; self.values.channels];
        };
        (0..self.values.channels)
            .map(|c| {
                let v = self.values.at(&look, c);
                let v = if self.kind == Kind::Rgb {
                    v.max(0.0)
                } else {
                    v
                };
                v * look.factor
            })
            .collect()
    }
}

/// The light and viewer directions of an isotropic surface point with cosines n·l
/// `cos_i`, n·v `cos_r` and l·v `l_dot_v`: l in the x–z plane (φi = 0), v at the
/// azimuth difference those cosines give, on the +y side.
pub fn local_directions(cos_i: f64, cos_r: f64, l_dot_v: f64) -> ([f64; 3], [f64; 3]) {
    let (ci, cr) = (cos_i.clamp(-1.0, 1.0), cos_r.clamp(-1.0, 1.0));
    let (si, sr) = ((1.0 - ci * ci).sqrt(), (1.0 - cr * cr).sqrt());
    let cos_phi = if si * sr > 1e-12 {
        ((l_dot_v - ci * cr) / (si * sr)).clamp(-1.0, 1.0)
    } else {
        1.0
    };
    let sin_phi = (1.0 - cos_phi * cos_phi).sqrt();
    ([si, 0.0, ci], [sr * cos_phi, sr * sin_phi, cr])
}

/// How a prepared file's values become camera RGB and spectra.
#[derive(Debug, Clone, PartialEq)]
enum Colour {
    /// The file's linear sRGB channels, clipped at 0, then the 3 × 3 map to camera RGB
    /// and the three spectra whose sRGB are the unit channels.
    Rgb {
        values: Channels,
        to_camera: [[f64; 3]; 3],
        unit_spectra: Box<[Spectrum; 3]>,
    },
    /// Tables of the spectra on gonio's bands and of their camera RGB, integrated once.
    Spectral { bands: Channels, camera: Channels },
}

/// A `.bsdf` file prepared for rendering with one camera and light: β (radiance factor,
/// π f_r) per camera channel and per band, white at 100 in camera RGB as
/// [`CameraDomain`] says.
#[derive(Debug, Clone, PartialEq)]
pub struct RglMaterial {
    geometry: Geometry,
    colour: Colour,
}

impl RglMaterial {
    /// Prepares `bsdf` for `domain`. A spectral file must cover the camera's 400–700 nm;
    /// bands beyond its wavelengths take its nearest one.
    pub fn new(bsdf: RglBsdf, domain: &CameraDomain) -> Result<Self, String> {
        let RglBsdf {
            geometry,
            values,
            kind,
        } = bsdf;
        let colour = match kind {
            Kind::Rgb => {
                let unit_spectra = spectral::srgb_unit_spectra();
                let camera = unit_spectra.map(|s| domain.rgb(&s));
                Colour::Rgb {
                    values,
                    to_camera: std::array::from_fn(|c| std::array::from_fn(|k| camera[k][c])),
                    unit_spectra: Box::new(unit_spectra),
                }
            }
            Kind::Spectral { wavelengths_nm } => {
                let (first, last) = (wavelengths_nm[0], wavelengths_nm[wavelengths_nm.len() - 1]);
                if first > 400.0 || last < 700.0 {
                    return Err(format!(
                        "wavelengths {first}–{last} nm do not cover the camera's 400–700 nm"
                    ));
                }
                let resample: Vec<Vec<f64>> = (0..BANDS)
                    .map(|b| interpolation_row(&wavelengths_nm, spectral::wavelength_nm(b)))
                    .collect();
                let weights = domain.weights();
                let to_camera: Vec<Vec<f64>> = weights
                    .iter()
                    .map(|w| {
                        (0..wavelengths_nm.len())
                            .map(|k| (0..BANDS).map(|b| w[b] * resample[b][k]).sum())
                            .collect()
                    })
                    .collect();
                Colour::Spectral {
                    bands: values.mapped(&resample),
                    camera: values.mapped(&to_camera),
                }
            }
        };
        Ok(Self { geometry, colour })
    }

    /// The lookup at a surface point and π/cos θo (cos θo at least [`MIN_COS`]), or
    /// `None` where no light reflects.
    fn lookup(&self, cos_i: f64, cos_r: f64, l_dot_v: f64) -> Option<(Lookup, f64)> {
        let (wi, wo) = local_directions(cos_i, cos_r, l_dot_v);
        let look = self.geometry.lookup(wi, wo)?;
        Some((look, PI / wo[2].max(MIN_COS)))
    }

    /// β per camera channel at a surface point (cosines n·l, n·v, l·v).
    pub fn beta(&self, cos_i: f64, cos_r: f64, l_dot_v: f64) -> [f64; 3] {
        let Some((look, scale)) = self.lookup(cos_i, cos_r, l_dot_v) else {
            return [0.0; 3];
        };
        let k = scale * look.factor;
        match &self.colour {
            Colour::Rgb {
                values, to_camera, ..
            } => {
                let srgb: [f64; 3] = std::array::from_fn(|c| values.at(&look, c).max(0.0));
                to_camera.map(|row| k * (0..3).map(|j| row[j] * srgb[j]).sum::<f64>())
            }
            Colour::Spectral { camera, .. } => std::array::from_fn(|c| k * camera.at(&look, c)),
        }
    }

    /// Spectral β at a surface point (cosines n·l, n·v, l·v); its camera RGB is
    /// [`RglMaterial::beta`].
    pub fn beta_spectrum(&self, cos_i: f64, cos_r: f64, l_dot_v: f64) -> Spectrum {
        let Some((look, scale)) = self.lookup(cos_i, cos_r, l_dot_v) else {
            return [0.0; BANDS];
        };
        let k = scale * look.factor;
        match &self.colour {
            Colour::Rgb {
                values,
                unit_spectra,
                ..
            } => {
                let srgb: [f64; 3] = std::array::from_fn(|c| values.at(&look, c).max(0.0));
                std::array::from_fn(|b| {
                    k * (0..3).map(|j| srgb[j] * unit_spectra[j][b]).sum::<f64>()
                })
            }
            Colour::Spectral { bands, .. } => std::array::from_fn(|b| k * bands.at(&look, b)),
        }
    }
}

/// Weights over `nodes` (increasing) of the linear interpolation at `x`, the nearest
/// end node beyond them.
fn interpolation_row(nodes: &[f64], x: f64) -> Vec<f64> {
    let mut row = vec![0.0; nodes.len()];
    let last = nodes.len() - 1;
    if x <= nodes[0] {
        row[0] = 1.0;
    } else if x >= nodes[last] {
        row[last] = 1.0;
    } else {
        let k = nodes.partition_point(|v| *v <= x) - 1;
        let t = (x - nodes[k]) / (nodes[k + 1] - nodes[k]);
        row[k] = 1.0 - t;
        row[k + 1] = t;
    }
    row
}
