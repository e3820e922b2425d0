//! Renders a capture of the cylinder scene: a pinhole camera ray per pixel meets the
//! cylinder, a point light with inverse-square falloff lights it, and the sample's
//! vector-form BRDF gives the reflected radiance.
//!
//! Raw count per channel c, above the black level:
//! `S_c = t · (ISO/100) · intensity/100 · β_c · cosθi · (1000 mm / |L − P|)² · vignetting`,
//! with β_c the radiance factor in the camera-RGB domain (eq. 4/5: the white reads
//! ρw·W_c, W_G = 100), so the ratio of a sample pixel to the white pixel at the same
//! geometry is β_c / (ρw W_c). Counts are rounded, offset by the black level and clipped
//! at the white level. Rows outside the two strips and columns that miss the cylinder
//! receive no light (the cylinder body and background are black).
//!
//! Vertical convention: the camera centre and the point light lie in the horizontal
//! plane z = 0 through the cylinder axis; a pixel row at sensor offset y sees the surface
//! at height z = −t·y, so strips above and below the optical axis are lit slightly out of
//! plane (by their real 3D geometry), identically when placed symmetrically.
//!
//! Separability: the ray–cylinder intersection, the surface normal and the in-plane
//! light and view vectors depend only on the column; a pixel adds only its height z
//! (exact, no approximation).
//!
//! A scene that names `[effects.misalignment]` breaks that symmetry: then every pixel's
//! ray meets the (possibly tilted) cylinder in 3D, seen from the moved, turned or
//! displaced camera, lit from where the misaligned arm puts the light (its zero offset
//! plus the θL's own angle error), and the strips are bands on the cylinder between the
//! heights the nominal strip rows see at its front
//! ([`crate::scene::SceneSetup::front_height_mm`]); the white strip reflects as the
//! misalignment's white reflectance error and falloff toward grazing say.

pub mod brdf;
pub mod effects;
pub mod reference;

use std::io::{Cursor, Write};
use std::path::Path;

use gonio_files::output::write_atomically;
use rayon::prelude::*;

use crate::scene::{Misalignment, Scene};
use brdf::Geom;
use effects::NoiseModel;

/// zlib level of a frame's strips: 13 MB for the gold scene's full 3872×2592 frame,
/// where level 1 gives 24 MB, and inflates faster.
const DEFLATE_LEVEL: u32 = 3;
/// Rows per strip of a frame's TIFF: a full-width strip of 16 rows is 363 kB of pixels.
const ROWS_PER_STRIP: u32 = 16;

/// An RGB image of sensor counts, rows top to bottom, channels interleaved, and how
/// they are stored in a 16-bit file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame16 {
    width: u32,
    height: u32,
    data: Vec<u16>,
    /// Left shift from a count to its stored value (16 − bit depth for linear counts).
    shift: u32,
}

impl Frame16 {
    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// Interleaved R, G, B sensor counts (or the 8-bit response's codes ×257), row-major.
    pub fn data(&self) -> &[u16] {
        &self.data
    }

    /// The pixel at column `x`, row `y` (panics outside the image).
    pub fn pixel(&self, x: u32, y: u32) -> [u16; 3] {
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// The values as stored in the file: counts in the top bits of 16 (an N-bit count
    /// times 2^(16−N)), so that the file spans the 16-bit range.
    pub fn stored(&self) -> Vec<u16> {
        self.data.iter().map(|&v| v << self.shift).collect()
    }

    /// Encodes as an RGB 16-bit TIFF that common readers decode with no extra codec
    /// (processing/src/capture.md): Deflate (zlib level `DEFLATE_LEVEL`) with
    /// horizontal differencing, values as [`Frame16::stored`], in strips of
    /// `ROWS_PER_STRIP` rows compressed in parallel.
    pub fn encode_tiff(&self) -> std::io::Result<Vec<u8>> {
        use tiff::encoder::TiffEncoder;
        use tiff::tags::{
            CompressionMethod, PhotometricInterpretation, PlanarConfiguration, Predictor, Tag,
        };
        let row_len = 3 * self.width as usize;
        let strips: Vec<Vec<u8>> = self
            .data
            .par_chunks(row_len * ROWS_PER_STRIP as usize)
            .map(|rows| {
                let mut bytes = Vec::with_capacity(2 * rows.len());
                for row in rows.chunks_exact(row_len) {
                    // Horizontal differencing: each sample minus the same channel's
                    // sample one pixel to the left, modulo 2^16.
                    let mut left = [0u16; 3];
                    for (i, &value) in row.iter().enumerate() {
                        let value = value << self.shift;
                        let before = std::mem::replace(&mut left[i % 3], value);
                        bytes.extend_from_slice(&value.wrapping_sub(before).to_le_bytes());
                    }
                }
                let mut zlib = flate2::write::ZlibEncoder::new(
                    Vec::with_capacity(bytes.len() / 4),
                    flate2::Compression::new(DEFLATE_LEVEL),
                );
                zlib.write_all(&bytes)?;
                zlib.finish()
            })
            .collect::<std::io::Result<_>>()?;
        // The directory: the strips' offsets and sizes, and how their pixels are stored.
        let write = || -> tiff::TiffResult<Vec<u8>> {
            let mut out = Cursor::new(Vec::new());
            let mut encoder = TiffEncoder::new(&mut out)?;
            let mut dir = encoder.image_directory()?;
            // Offsets and sizes are 32-bit in a classic TIFF.
            let too_large = |_| std::io::Error::other("over 4 GB");
            let mut offsets = Vec::with_capacity(strips.len());
            let mut counts = Vec::with_capacity(strips.len());
            for strip in &strips {
                let offset = dir.write_data(strip.as_slice())?;
                offsets.push(u32::try_from(offset).map_err(too_large)?);
                counts.push(u32::try_from(strip.len()).map_err(too_large)?);
            }
            dir.write_tag(Tag::ImageWidth, self.width)?;
            dir.write_tag(Tag::ImageLength, self.height)?;
            dir.write_tag(Tag::BitsPerSample, &[16u16, 16, 16][..])?;
            dir.write_tag(Tag::Compression, CompressionMethod::Deflate.to_u16())?;
            dir.write_tag(
                Tag::PhotometricInterpretation,
                PhotometricInterpretation::RGB.to_u16(),
            )?;
            dir.write_tag(Tag::StripOffsets, offsets.as_slice())?;
            dir.write_tag(Tag::SamplesPerPixel, 3u16)?;
            dir.write_tag(Tag::RowsPerStrip, ROWS_PER_STRIP)?;
            dir.write_tag(Tag::StripByteCounts, counts.as_slice())?;
            dir.write_tag(
                Tag::PlanarConfiguration,
                PlanarConfiguration::Chunky.to_u16(),
            )?;
            dir.write_tag(Tag::Predictor, Predictor::Horizontal.to_u16())?;
            dir.finish()?;
            Ok(out.into_inner())
        };
        write().map_err(|e| std::io::Error::other(format!("TIFF encoding: {e}")))
    }

    /// Writes the TIFF atomically at `path`.
    pub fn write_tiff(&self, path: &Path) -> std::io::Result<()> {
        write_atomically(path, &self.encode_tiff()?)
    }
}

/// One exposure: light angle (degrees), shutter (s), ISO, and an index that varies the
/// noise between otherwise identical captures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shot {
    pub theta_l_deg: f64,
    pub shutter_s: f64,
    pub iso: u32,
    pub frame_index: u64,
}

/// How the stored values relate to light, as the capture sidecar states it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FileLevels {
    /// Black level in stored units.
    pub black_level: u32,
    /// White (clipping) level in stored units.
    pub white_level: u32,
    /// `true`: the 8-bit non-linear response (sidecar `"response":"nonlinear"`).
    pub nonlinear: bool,
    /// Bits of each stored 16-bit value that carry signal, at its top: the sensor's bit
    /// depth, or 8 for the non-linear response (each code stored ×257).
    pub significant_bits: u32,
}

impl FileLevels {
    /// Left shift from a rendered count to its stored value.
    fn shift(&self) -> u32 {
        if self.nonlinear {
            0
        } else {
            16 - self.significant_bits
        }
    }
}

/// The levels of the files `scene` renders.
pub fn file_levels(scene: &Scene) -> FileLevels {
    match scene.effects().response {
        Some(_) => FileLevels {
            black_level: 0,
            white_level: 65_535,
            nonlinear: true,
            significant_bits: 8,
        },
        None => {
            let camera = scene.camera();
            let shift = 16 - camera.bit_depth;
            FileLevels {
                black_level: camera.black_level << shift,
                white_level: camera.white_level << shift,
                nonlinear: false,
                significant_bits: camera.bit_depth,
            }
        }
    }
}

/// Renders at the scene's ISO with frame index 0.
pub fn render_frame(scene: &Scene, theta_l_deg: f64, shutter_s: f64) -> Frame16 {
    render(
        scene,
        &Shot {
            theta_l_deg,
            shutter_s,
            iso: scene.camera().iso,
            frame_index: 0,
        },
    )
}

/// What one column sees (in-plane parts of the vectors, mm).
#[derive(Debug, Clone, Copy)]
struct Column {
    /// Ray parameter of the hit: the hit's height is z = −t·y for sensor offset y.
    t: f64,
    x_mm: f64,
    n_l: f64,
    n_v: f64,
    l_v: f64,
    l2: f64,
    v2: f64,
    theta_i_deg: f64,
    theta_r_deg: f64,
}

fn columns(scene: &Scene, theta_l_deg: f64) -> Vec<Option<Column>> {
    let s = scene.setup();
    let (f, pitch, r, dc) = (
        s.focal_length_mm,
        s.pixel_pitch_um / 1000.0,
        s.cylinder_radius_mm,
        s.camera_distance_mm,
    );
    let (sin_l, cos_l) = theta_l_deg.to_radians().sin_cos();
    let light = [s.light_distance_mm * cos_l, s.light_distance_mm * sin_l];
    let cx = s.cx();
    (0..s.image_width)
        .map(|u| {
            let x_mm = (f64::from(u) - cx) * pitch;
            // Ray (dc, 0) + t·(−f, x) against x² + y² = r².
            let a = f * f + x_mm * x_mm;
            let half_b = -dc * f;
            let disc = half_b * half_b - a * (dc * dc - r * r);
            if disc < 0.0 {
                return None;
            }
            // Near root in the cancellation-free form c / (−b/2 + √disc).
            let t = (dc * dc - r * r) / (-half_b + disc.sqrt());
            let p = [dc - t * f, t * x_mm];
            let n = [p[0] / r, p[1] / r];
            let l = [light[0] - p[0], light[1] - p[1]];
            let v = [t * f, -t * x_mm];
            let dot = |a: [f64; 2], b: [f64; 2]| a[0] * b[0] + a[1] * b[1];
            let tangent = [-n[1], n[0]];
            let n_v = dot(n, v);
            if n_v <= 0.0 {
                return None;
            }
            Some(Column {
                t,
                x_mm,
                n_l: dot(n, l),
                n_v,
                l_v: dot(l, v),
                l2: dot(l, l),
                v2: dot(v, v),
                theta_i_deg: dot(tangent, l).atan2(dot(n, l)).to_degrees(),
                theta_r_deg: -dot(tangent, v).atan2(n_v).to_degrees(),
            })
        })
        .collect()
}

#[derive(Clone, Copy, PartialEq)]
enum Strip {
    Sample,
    White,
    Dark,
}

/// What a pixel sees at its surface point: cosines of unit vectors, the squared light
/// distance (mm²) and the signed in-plane angles (degrees).
#[derive(Debug, Clone, Copy)]
struct Local {
    cos_i: f64,
    cos_r: f64,
    l_dot_v: f64,
    l2: f64,
    theta_i_deg: f64,
    theta_r_deg: f64,
}

impl Column {
    /// The pixel of this column at sensor height `y_mm`; `None` where it is unlit.
    #[inline]
    fn at(&self, y_mm: f64) -> Option<Local> {
        let z = -self.t * y_mm;
        let z2 = z * z;
        let l2 = self.l2 + z2;
        let (l_len, v_len) = (l2.sqrt(), (self.v2 + z2).sqrt());
        let cos_i = self.n_l / l_len;
        if cos_i <= 0.0 {
            return None;
        }
        Some(Local {
            cos_i,
            cos_r: self.n_v / v_len,
            l_dot_v: (self.l_v + z2) / (l_len * v_len),
            l2,
            theta_i_deg: self.theta_i_deg,
            theta_r_deg: self.theta_r_deg,
        })
    }
}

type Vec3 = [f64; 3];

fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The world of a misaligned scene for one light angle (see
/// [`crate::scene::Misalignment`]): world frame as the scene's setup, z up.
struct Misaligned {
    camera: Vec3,
    /// f times the unit optical axis, and the unit image right and up vectors (mm).
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    /// Unit cylinder axis.
    axis: Vec3,
    radius: f64,
    light: Vec3,
    /// Heights along the axis (low, high) of the sample and white bands, mm.
    sample_band: (f64, f64),
    white_band: (f64, f64),
}

impl Misaligned {
    fn new(scene: &Scene, m: &Misalignment, theta_l_deg: f64) -> Self {
        let s = scene.setup();
        let (sin_y, cos_y) = m.camera_yaw_deg.to_radians().sin_cos();
        let (sin_r, cos_r) = m.camera_roll_deg.to_radians().sin_cos();
        let (sin_t, cos_t) = m.cylinder_tilt_deg.to_radians().sin_cos();
        let arm_error = m.arm_angle_error_deg(scene.theta_l_deg(), theta_l_deg);
        let (sin_l, cos_l) = (theta_l_deg + m.arm_zero_offset_deg + arm_error)
            .to_radians()
            .sin_cos();
        let light = s.light_distance_mm + m.light_distance_error_mm;
        let f = s.focal_length_mm;
        // Rows r0..=r1 cover sensor rows r0 − ½ to r1 + ½; lower rows are higher up.
        let band = |rows: [u32; 2]| {
            (
                s.front_height_mm(f64::from(rows[1]) + 0.5),
                s.front_height_mm(f64::from(rows[0]) - 0.5),
            )
        };
        Self {
            camera: [
                s.camera_distance_mm + m.camera_distance_error_mm,
                m.camera_offset_mm,
                0.0,
            ],
            forward: [-f * cos_y, -f * sin_y, 0.0],
            // Yawed right (−sin ψ, cos ψ, 0) and up +z, turned by the roll about the
            // optical axis (right toward up).
            right: [-sin_y * cos_r, cos_y * cos_r, sin_r],
            up: [sin_y * sin_r, -cos_y * sin_r, cos_r],
            axis: [0.0, sin_t, cos_t],
            radius: s.cylinder_radius_mm,
            light: [light * cos_l, light * sin_l, 0.0],
            sample_band: band(s.sample_rows),
            white_band: band(s.white_rows),
        }
    }

    /// What the pixel at sensor offsets (`x_mm` right, `y_mm` down) of the principal
    /// point sees: the strip it falls on and its local geometry; `None` where the ray
    /// misses the cylinder, the point is unlit or lies outside both strips.
    fn pixel(&self, x_mm: f64, y_mm: f64) -> Option<(Strip, Local)> {
        let d: Vec3 =
            std::array::from_fn(|k| self.forward[k] + x_mm * self.right[k] - y_mm * self.up[k]);
        // Components ⊥ the axis: |C⊥ + t·d⊥|² = r², near root t = c / (−b/2 + √disc).
        let perp = |v: Vec3| {
            let along = dot(v, self.axis);
            [
                v[0] - along * self.axis[0],
                v[1] - along * self.axis[1],
                v[2] - along * self.axis[2],
            ]
        };
        let (c, dp) = (perp(self.camera), perp(d));
        let a = dot(dp, dp);
        let half_b = dot(c, dp);
        let c0 = dot(c, c) - self.radius * self.radius;
        let disc = half_b * half_b - a * c0;
        if disc <= 0.0 || half_b >= 0.0 {
            return None;
        }
        let t = c0 / (-half_b + disc.sqrt());
        let p: Vec3 = std::array::from_fn(|k| self.camera[k] + t * d[k]);
        let height = dot(p, self.axis);
        let strip = if (self.sample_band.0..=self.sample_band.1).contains(&height) {
            Strip::Sample
        } else if (self.white_band.0..=self.white_band.1).contains(&height) {
            Strip::White
        } else {
            return None;
        };
        let n = perp(p).map(|x| x / self.radius);
        let l: Vec3 = std::array::from_fn(|k| self.light[k] - p[k]);
        let v: Vec3 = d.map(|x| -t * x);
        let (l2, v2) = (dot(l, l), dot(v, v));
        let (n_l, n_v) = (dot(n, l), dot(n, v));
        if n_l <= 0.0 || n_v <= 0.0 {
            return None;
        }
        let (l_len, v_len) = (l2.sqrt(), v2.sqrt());
        // In-plane angles in the cross-section plane: tangent = axis × n.
        let a = self.axis;
        let tangent = [
            a[1] * n[2] - a[2] * n[1],
            a[2] * n[0] - a[0] * n[2],
            a[0] * n[1] - a[1] * n[0],
        ];
        Some((
            strip,
            Local {
                cos_i: n_l / l_len,
                cos_r: n_v / v_len,
                l_dot_v: dot(l, v) / (l_len * v_len),
                l2,
                theta_i_deg: dot(tangent, l).atan2(n_l).to_degrees(),
                theta_r_deg: -dot(tangent, v).atan2(n_v).to_degrees(),
            },
        ))
    }
}

/// Per-frame constants of the light reaching the sensor.
struct Lighting<'a> {
    scene: &'a Scene,
    /// Counts per unit β·cosθi at 1000 mm: t · ISO/100 · intensity/100.
    scale: f64,
    white_beta: [f64; 3],
    /// The white's falloff toward grazing: its β × (1 − a·(1 − cos θi)); 0 when Lambertian.
    white_falloff: f64,
    /// Retro-reflection kr and w².
    retro: Option<([f64; 3], f64)>,
    vignetting: Option<f64>,
}

impl Lighting<'_> {
    /// Signal (counts above black) of a lit pixel at sensor offsets (`x_mm`, `y_mm`)
    /// seeing `local` on `strip`.
    #[inline]
    fn signal(&self, local: &Local, strip: Strip, x_mm: f64, y_mm: f64) -> [f64; 3] {
        let beta = if strip == Strip::White {
            if self.white_falloff == 0.0 {
                self.white_beta
            } else {
                let factor = 1.0 - self.white_falloff * (1.0 - local.cos_i.clamp(0.0, 1.0));
                self.white_beta.map(|b| b * factor)
            }
        } else {
            let g = Geom::new(
                local.cos_i,
                local.cos_r,
                local.l_dot_v,
                local.theta_i_deg,
                local.theta_r_deg,
            );
            let mut beta = self.scene.material().beta(&g);
            if let Some((kr, w2)) = self.retro {
                let lobe = brdf::retro_lobe(local.l_dot_v, w2);
                for (b, k) in beta.iter_mut().zip(kr) {
                    *b += k * lobe;
                }
            }
            beta
        };
        let mut gain = self.scale * local.cos_i * 1e6 / local.l2;
        if let Some(strength) = self.vignetting {
            let f = self.scene.setup().focal_length_mm;
            gain *= effects::vignetting_gain(strength, f, x_mm, y_mm);
        }
        beta.map(|b| b * gain)
    }
}

/// How pixels are traced: separably per column, or each in 3D (misaligned scenes).
enum View {
    Columns(Vec<Option<Column>>),
    Misaligned(Misaligned),
}

/// Quantises one row of signals (counts above black, `None` where no light arrives)
/// into `out`, with noise when the scene has it (`rng` gives the row's generator).
#[inline]
fn fill_row(
    out: &mut [u16],
    signal: impl Fn(usize) -> Option<[f64; 3]>,
    noise: Option<&NoiseModel>,
    rng: impl FnOnce() -> rand_pcg::Pcg64Mcg,
    quantise: &impl Fn(f64) -> u16,
    dark: u16,
) {
    match noise {
        None => {
            for (u, px) in out.chunks_exact_mut(3).enumerate() {
                match signal(u) {
                    Some(signal) => {
                        for (v, s) in px.iter_mut().zip(signal) {
                            *v = quantise(s);
                        }
                    }
                    None => px.fill(dark),
                }
            }
        }
        Some(model) => {
            let mut rng = rng();
            for (u, px) in out.chunks_exact_mut(3).enumerate() {
                let signal = signal(u).unwrap_or([0.0; 3]);
                for (v, s) in px.iter_mut().zip(signal) {
                    *v = quantise(model.apply(s, &mut rng));
                }
            }
        }
    }
}

/// Renders one exposure.
pub fn render(scene: &Scene, shot: &Shot) -> Frame16 {
    let setup = scene.setup();
    let (width, height) = (setup.image_width, setup.image_height);
    let camera = scene.camera();
    let effects = scene.effects();
    let view = match &effects.misalignment {
        Some(m) => View::Misaligned(Misaligned::new(scene, m, shot.theta_l_deg)),
        None => View::Columns(columns(scene, shot.theta_l_deg)),
    };
    let pitch = setup.pixel_pitch_um / 1000.0;
    let (cx, cy) = (setup.cx(), setup.cy());
    let lighting = Lighting {
        scene,
        scale: shot.shutter_s * f64::from(shot.iso) / 100.0 * scene.light_intensity() / 100.0,
        white_beta: scene
            .camera_domain()
            .white_rgb()
            .map(|w| w * scene.rendered_white_reflectance()),
        white_falloff: scene.rendered_white_falloff(),
        retro: effects
            .retro_reflection
            .as_ref()
            .map(|r| (r.kr, r.width_deg.to_radians().tan().powi(2))),
        vignetting: effects.vignetting.as_ref().map(|v| v.strength),
    };
    let noise = effects.noise.as_ref().map(|n| NoiseModel::new(n, shot.iso));
    let frame_seed = effects::mix(
        effects.seed
            ^ effects::mix(shot.theta_l_deg.to_bits())
            ^ effects::mix(shot.shutter_s.to_bits()).rotate_left(17)
            ^ effects::mix(u64::from(shot.iso) ^ (shot.frame_index << 20)).rotate_left(31),
    );
    let black = f64::from(camera.black_level);
    let white_level = f64::from(camera.white_level);
    let response = effects
        .response
        .as_ref()
        .map(|r| effects::response_table(r, camera.black_level, camera.white_level));
    // Round half up by truncating a non-negative value (cheaper than `round`).
    let quantise = |s: f64| {
        let v = ((black + s).clamp(0.0, white_level) + 0.5) as u16;
        match &response {
            Some(table) => table[usize::from(v)],
            None => v,
        }
    };
    let dark = quantise(0.0);

    let row_len = 3 * width as usize;
    let mut data = vec![0u16; row_len * height as usize];
    data.par_chunks_mut(row_len)
        .enumerate()
        .for_each(|(row, out)| {
            let row = row as u32;
            let y_mm = (f64::from(row) - cy) * pitch;
            let rng = || NoiseModel::row_rng(frame_seed, row);
            match &view {
                View::Columns(cols) => {
                    let strip = if (setup.sample_rows[0]..=setup.sample_rows[1]).contains(&row) {
                        Strip::Sample
                    } else if (setup.white_rows[0]..=setup.white_rows[1]).contains(&row) {
                        Strip::White
                    } else {
                        Strip::Dark
                    };
                    let signal = |u: usize| {
                        if strip == Strip::Dark {
                            return None;
                        }
                        let col = cols[u].as_ref()?;
                        let local = col.at(y_mm)?;
                        Some(lighting.signal(&local, strip, col.x_mm, y_mm))
                    };
                    fill_row(out, signal, noise.as_ref(), rng, &quantise, dark);
                }
                View::Misaligned(world) => {
                    let signal = |u: usize| {
                        let x_mm = (u as f64 - cx) * pitch;
                        let (strip, local) = world.pixel(x_mm, y_mm)?;
                        Some(lighting.signal(&local, strip, x_mm, y_mm))
                    };
                    fill_row(out, signal, noise.as_ref(), rng, &quantise, dark);
                }
            }
        });
    if let Some(hot) = &effects.hot_pixels {
        let stuck = match &response {
            Some(table) => table[camera.white_level as usize],
            None => camera.white_level as u16,
        };
        for p in effects::hot_pixel_positions(hot.count, width, height, effects.seed) {
            data[3 * p..3 * p + 3].fill(stuck);
        }
    }
    Frame16 {
        width,
        height,
        data,
        shift: file_levels(scene).shift(),
    }
}
