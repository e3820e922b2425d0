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

pub mod brdf;
pub mod effects;
pub mod reference;

use std::io::Cursor;
use std::path::Path;

use gonio_drivers::atomic_file::write_atomically;
use rayon::prelude::*;

use crate::scene::Scene;
use brdf::Geom;
use effects::NoiseModel;

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
    /// (docs/ARCHITECTURE.md, "Captures"): Deflate with horizontal differencing, values
    /// as [`Frame16::stored`].
    pub fn encode_tiff(&self) -> std::io::Result<Vec<u8>> {
        use tiff::encoder::{colortype::RGB16, Compression, DeflateLevel, Predictor, TiffEncoder};
        let stored;
        let values = if self.shift == 0 {
            &self.data
        } else {
            stored = self.stored();
            &stored
        };
        let mut out = Cursor::new(Vec::new());
        TiffEncoder::new(&mut out)
            .and_then(|e| {
                e.with_compression(Compression::Deflate(DeflateLevel::Fast))
                    .with_predictor(Predictor::Horizontal)
                    .write_image::<RGB16>(self.width, self.height, values)
            })
            .map_err(|e| std::io::Error::other(format!("TIFF encoding: {e}")))?;
        Ok(out.into_inner())
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

/// Per-frame constants of the light reaching the sensor.
struct Lighting<'a> {
    scene: &'a Scene,
    /// Counts per unit β·cosθi at 1000 mm: t · ISO/100 · intensity/100.
    scale: f64,
    white_beta: [f64; 3],
    /// Retro-reflection kr and w².
    retro: Option<([f64; 3], f64)>,
    vignetting: Option<f64>,
}

impl Lighting<'_> {
    /// Signal (counts above black) of the pixel at sensor height `y_mm` in column
    /// `col` of a strip; `None` where no light arrives.
    #[inline]
    fn signal(&self, col: &Column, y_mm: f64, strip: Strip) -> Option<[f64; 3]> {
        if strip == Strip::Dark {
            return None;
        }
        let z = -col.t * y_mm;
        let z2 = z * z;
        let l2 = col.l2 + z2;
        let (l_len, v_len) = (l2.sqrt(), (col.v2 + z2).sqrt());
        let cos_i = col.n_l / l_len;
        if cos_i <= 0.0 {
            return None;
        }
        let beta = if strip == Strip::White {
            self.white_beta
        } else {
            let l_v = (col.l_v + z2) / (l_len * v_len);
            let g = Geom::new(
                cos_i,
                col.n_v / v_len,
                l_v,
                col.theta_i_deg,
                col.theta_r_deg,
            );
            let mut beta = self.scene.material().beta(&g);
            if let Some((kr, w2)) = self.retro {
                let lobe = brdf::retro_lobe(l_v, w2);
                for (b, k) in beta.iter_mut().zip(kr) {
                    *b += k * lobe;
                }
            }
            beta
        };
        let mut gain = self.scale * cos_i * 1e6 / l2;
        if let Some(strength) = self.vignetting {
            let f = self.scene.setup().focal_length_mm;
            gain *= effects::vignetting_gain(strength, f, col.x_mm, y_mm);
        }
        Some(beta.map(|b| b * gain))
    }
}

/// Renders one exposure.
pub fn render(scene: &Scene, shot: &Shot) -> Frame16 {
    let setup = scene.setup();
    let (width, height) = (setup.image_width, setup.image_height);
    let camera = scene.camera();
    let effects = scene.effects();
    let cols = columns(scene, shot.theta_l_deg);
    let pitch = setup.pixel_pitch_um / 1000.0;
    let cy = setup.cy();
    let lighting = Lighting {
        scene,
        scale: shot.shutter_s * f64::from(shot.iso) / 100.0 * scene.light_intensity() / 100.0,
        white_beta: scene
            .camera_domain()
            .white_rgb()
            .map(|w| w * scene.white_reflectance()),
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
            let strip = if (setup.sample_rows[0]..=setup.sample_rows[1]).contains(&row) {
                Strip::Sample
            } else if (setup.white_rows[0]..=setup.white_rows[1]).contains(&row) {
                Strip::White
            } else {
                Strip::Dark
            };
            let y_mm = (f64::from(row) - cy) * pitch;
            match &noise {
                None => {
                    for (col, px) in cols.iter().zip(out.chunks_exact_mut(3)) {
                        match col.and_then(|col| lighting.signal(&col, y_mm, strip)) {
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
                    let mut rng = NoiseModel::row_rng(frame_seed, row);
                    for (col, px) in cols.iter().zip(out.chunks_exact_mut(3)) {
                        let signal = col
                            .and_then(|col| lighting.signal(&col, y_mm, strip))
                            .unwrap_or([0.0; 3]);
                        for (v, s) in px.iter_mut().zip(signal) {
                            *v = quantise(model.apply(s, &mut rng));
                        }
                    }
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
