//! The timing model a scan's time left is estimated from (docs/ARCHITECTURE.md,
//! "Daemon"; server/src/daemon.md, "Time left"): arm moves under the controller's
//! trapezoidal motion profile, captures as shutter time plus download latency (and an
//! emulated camera's rendering), processing steps from what processing costs on this
//! machine per unit of work ([`Costs`]: measured at the daemon's first start, else the
//! stated defaults) times the scan's frame size, bracket, θL count and models. Times
//! are wall-clock seconds.

use gonio_mock_hw::camera::CaptureTiming;
use gonio_mock_hw::grbl::{move_duration_s, GrblConfig};
use gonio_processing::fit::JUDGED_PER_THETA_L;
use serde::{Deserialize, Serialize};

use super::plan::{Step, AUTO_FIT, FIT_MODELS};

/// Metering shutter time, seconds (the allowed one at or below it is used).
pub const METER_START_S: f64 = 1.0 / 60.0;
/// The bracket a θL is expected to need before its metering says (seconds, longest
/// first): the typical one of the example scenes, the medians of the frame count and
/// of each frame's shutter over the brackets every built-in scene meters to at the θL
/// of its scan (`lanes::hardware::metering`'s test measures them and holds this to it).
pub(crate) const EXPECTED_BRACKET_S: [f64; 2] = [6.0, 1.0 / 15.0];
/// A homing cycle in controller seconds.
const HOMING_S: f64 = 3.0;
/// The frame size assumed when the setup gives none: a full-size 3872×2592 frame.
const DEFAULT_FRAME: (u32, u32) = (3872, 2592);

/// What processing costs on this machine per unit of work, seconds. Measured by the
/// timing probe at the daemon's first start (`lanes/timing_probe.rs`, cached in
/// DATA/processing-costs.json); [`Costs::DEFAULT`] until then.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Costs {
    /// Rendering and writing one emulated frame, seconds per megapixel.
    pub frame_s_per_mpx: f64,
    /// Reading a frame whole (decoding it, as the metering step does), seconds per
    /// megapixel.
    pub read_s_per_mpx: f64,
    /// An HDR merge (decoding, merging, writing the map), seconds per megapixel per
    /// frame of the bracket.
    pub hdr_s_per_mpx_frame: f64,
    /// A samples step's extraction, seconds per pixel column per frame of the bracket
    /// (it decodes and reads the strip rows only, whatever the frame's height).
    pub extraction_s_per_column_frame: f64,
    /// A samples step's live fits, seconds per sample point fitted (every θL so far).
    pub live_fit_s_per_point: f64,
    /// Sample points one θL yields per pixel column of the frame.
    pub points_per_column: f64,
    /// Gathering `samples.csv`, seconds per point.
    pub extract_s_per_point: f64,
    /// Each final fit of [`FIT_MODELS`], in that order, seconds per point.
    pub fit_s_per_point: [f64; 3],
    /// The [`AUTO_FIT`] (every candidate, each θL held out in turn) run after the
    /// per-model fits, whose budgets it shares: seconds per point judged, and seconds
    /// whatever the points.
    pub auto_s_per_point: f64,
    pub auto_s: f64,
}

impl Costs {
    /// The stated defaults: a debug build of the daemon on one core of a 2-core
    /// virtual machine, measured by the timing probe there (reading a frame and the
    /// extraction per column, measured later with an optimized build, scaled by 2.5,
    /// the ratio of the other costs between the two). Used until this machine's own
    /// measurement is in.
    pub const DEFAULT: Costs = Costs {
        frame_s_per_mpx: 0.28,
        read_s_per_mpx: 0.1,
        hdr_s_per_mpx_frame: 0.18,
        extraction_s_per_column_frame: 7.0e-5,
        live_fit_s_per_point: 3.0e-4,
        points_per_column: 0.36,
        extract_s_per_point: 8.0e-5,
        fit_s_per_point: [5.8e-4, 5.3e-4, 5.3e-4],
        auto_s_per_point: 2.0e-3,
        auto_s: 2.5,
    };

    /// Whether every cost is a finite number ≥ 0 (a cache that says otherwise is
    /// measured again).
    pub fn is_valid(&self) -> bool {
        [
            self.frame_s_per_mpx,
            self.read_s_per_mpx,
            self.hdr_s_per_mpx_frame,
            self.extraction_s_per_column_frame,
            self.live_fit_s_per_point,
            self.points_per_column,
            self.extract_s_per_point,
            self.auto_s_per_point,
            self.auto_s,
        ]
        .iter()
        .chain(&self.fit_s_per_point)
        .all(|c| c.is_finite() && *c >= 0.0)
    }
}

/// Where a step sits in its scan, for the priors that depend on it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Place {
    /// θL in the scan.
    pub theta_count: usize,
    /// θL up to and including this step's (a samples step fits every one of them).
    pub theta_rank: usize,
    /// Frames of this step's bracket (known, or expected before metering).
    pub frames: usize,
}

/// What the devices' steps take, before any is measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timing {
    /// The arm's maximum rate, degrees per minute.
    pub arm_rate_deg_per_min: f64,
    /// The arm's acceleration, degrees per second².
    pub arm_accel_deg_per_s2: f64,
    /// Wall seconds per controller second (an emulator's time scale; 1 for a real arm).
    pub arm_time_scale: f64,
    /// The camera's capture timing (its own time scale included).
    pub capture: CaptureTiming,
    /// Whether the camera is emulated: its frames are rendered on this machine.
    pub rendered: bool,
    /// Frame width and height, pixels.
    pub frame: (u32, u32),
    /// What processing costs on this machine.
    pub costs: Costs,
    /// This machine's cores.
    pub cores: usize,
    /// Captured brackets awaiting processing at which the arm waits
    /// (`processing.max_backlog`).
    pub max_backlog: usize,
}

impl Timing {
    /// The emulators' timing, exactly.
    pub fn emulated(grbl: &GrblConfig, capture: CaptureTiming) -> Self {
        Timing {
            arm_rate_deg_per_min: grbl.max_rate_deg_per_min,
            arm_accel_deg_per_s2: grbl.accel_deg_per_s2,
            arm_time_scale: grbl.time_scale,
            capture,
            rendered: false,
            frame: DEFAULT_FRAME,
            costs: Costs::DEFAULT,
            cores: std::thread::available_parallelism().map_or(2, |n| n.get()),
            max_backlog: 2,
        }
    }

    /// Real devices: the emulated arm board's rates and the emulated camera's timing
    /// in real time, a prior that measurement of the scan's own steps corrects.
    pub fn real() -> Self {
        Self::emulated(
            &GrblConfig::arm_board(),
            CaptureTiming {
                time_scale: 1.0,
                ..CaptureTiming::default()
            },
        )
    }

    /// This timing with frames of `width`×`height` pixels (0 keeps the default).
    pub fn with_frame(self, width: u32, height: u32) -> Self {
        let frame = if width > 0 && height > 0 {
            (width, height)
        } else {
            DEFAULT_FRAME
        };
        Timing { frame, ..self }
    }

    /// Megapixels of a frame.
    pub fn frame_mpx(&self) -> f64 {
        f64::from(self.frame.0) * f64::from(self.frame.1) / 1e6
    }

    /// Sample points one θL is expected to yield.
    fn points_per_theta(&self) -> f64 {
        self.costs.points_per_column * f64::from(self.frame.0)
    }

    /// Expected seconds of one capture at `shutter_s`: the exposure and download, or
    /// an emulated frame's rendering and writing if that takes longer (the emulator
    /// renders while the exposure runs).
    pub fn capture_s(&self, shutter_s: f64) -> f64 {
        let exposure = self.capture.capture_duration_s(shutter_s);
        if self.rendered {
            exposure.max(self.costs.frame_s_per_mpx * self.frame_mpx())
        } else {
            exposure
        }
    }

    /// Seconds of an emulated frame's rendering and writing on this machine's cores
    /// (0 with a real camera): the part of a capture that draws on them.
    pub fn render_s(&self) -> f64 {
        if self.rendered {
            self.costs.frame_s_per_mpx * self.frame_mpx()
        } else {
            0.0
        }
    }

    /// The part of a capture's seconds during which an emulated frame renders (0 with a
    /// real camera): its rendering over the seconds the capture is expected to take at
    /// these shutter times, at most all of them (a frame whose rendering outlasts its
    /// exposure renders for the whole capture, however long that turns out to be).
    pub fn render_fraction(&self, shutter_s: &[f64]) -> f64 {
        let capture_s: f64 = shutter_s.iter().map(|&s| self.capture_s(s)).sum();
        if capture_s > 0.0 {
            (shutter_s.len() as f64 * self.render_s() / capture_s).min(1.0)
        } else {
            0.0
        }
    }

    /// The share of the cores the processing lane has while a frame renders. The
    /// processing threads (the lane's pool, one more than the cores) run 10 nice
    /// levels below the renderer's (one per core; `lanes/processing.rs`), and the
    /// kernel shares the cores by the threads' weights: 1024 at nice 0, 110 at nice 10.
    pub fn processing_share_while_rendering(&self) -> f64 {
        const WEIGHT_NICE_0: f64 = 1024.0;
        const WEIGHT_NICE_10: f64 = 110.0;
        let cores = self.cores.max(1) as f64;
        let processing = (cores + 1.0) * WEIGHT_NICE_10;
        processing / (cores * WEIGHT_NICE_0 + processing)
    }

    /// Expected seconds of decoding one frame (part of an HDR step; the processing lane
    /// decodes a bracket's captured frames ahead of its step when it has nothing else).
    pub fn decode_s(&self) -> f64 {
        (self.costs.read_s_per_mpx * self.frame_mpx())
            .min(self.costs.hdr_s_per_mpx_frame * self.frame_mpx())
    }

    /// Frames of the bracket a θL is expected to need before its metering says.
    pub fn expected_frames(&self) -> usize {
        EXPECTED_BRACKET_S.len()
    }

    /// Expected seconds of the captures of a bracket the scan has not metered yet.
    pub fn expected_bracket_s(&self) -> f64 {
        EXPECTED_BRACKET_S.iter().map(|&s| self.capture_s(s)).sum()
    }

    /// Expected seconds of the automatic choice on a scan of `theta_count` θL: its
    /// candidates are fitted and judged on the points judged only
    /// ([`JUDGED_PER_THETA_L`] at most per θL), and its final fit's budget is the one
    /// the same model's fit step makes (they share it, in a scan as in the probe, which
    /// measures the choice after the per-model fits).
    fn auto_s(&self, theta_count: usize) -> f64 {
        let per_theta = self.points_per_theta();
        let stride = (per_theta / JUDGED_PER_THETA_L as f64).ceil().max(1.0);
        let judged = per_theta / stride * theta_count as f64;
        self.costs.auto_s + self.costs.auto_s_per_point * judged
    }

    /// Expected seconds of `step` at `place` in its scan, with the arm at `from_deg`
    /// before it.
    pub fn prior_s(&self, step: &Step, from_deg: f64, place: &Place) -> f64 {
        let travel_s = |to_deg: f64| {
            move_duration_s(
                to_deg - from_deg,
                self.arm_rate_deg_per_min,
                self.arm_accel_deg_per_s2,
            ) * self.arm_time_scale
        };
        let costs = &self.costs;
        let bracket_mpx = self.frame_mpx() * place.frames as f64;
        let bracket_columns = f64::from(self.frame.0) * place.frames as f64;
        let points = self.points_per_theta() * place.theta_count as f64;
        match step {
            Step::Home => travel_s(0.0) + HOMING_S * self.arm_time_scale,
            Step::Move { theta_l } => travel_s(*theta_l),
            // A capture, then reading its frame to choose the bracket.
            Step::Meter { .. } => {
                self.capture_s(METER_START_S) + costs.read_s_per_mpx * self.frame_mpx()
            }
            Step::Capture { shutter_s, .. } => self.capture_s(*shutter_s),
            Step::Samples { .. } => {
                costs.extraction_s_per_column_frame * bracket_columns
                    + costs.live_fit_s_per_point * self.points_per_theta() * place.theta_rank as f64
            }
            Step::Hdr { .. } => costs.hdr_s_per_mpx_frame * bracket_mpx,
            Step::Extract => costs.extract_s_per_point * points,
            Step::Fit { model } if model == AUTO_FIT.0 => self.auto_s(place.theta_count),
            Step::Fit { model } => {
                let index = FIT_MODELS.iter().position(|(name, _)| name == model);
                let per_point =
                    index.map_or(costs.fit_s_per_point[0], |i| costs.fit_s_per_point[i]);
                per_point * points
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn priors_follow_the_devices_time_scales() {
        let grbl = GrblConfig {
            time_scale: 0.1,
            ..GrblConfig::arm_board()
        };
        let capture = CaptureTiming {
            time_scale: 0.1,
            ..CaptureTiming::default()
        };
        let place = Place {
            theta_count: 6,
            theta_rank: 1,
            frames: 2,
        };
        let fast = Timing::emulated(&grbl, capture);
        let real = Timing::real();
        let move_20 = Step::Move { theta_l: -20.0 };
        let expected = move_duration_s(20.0, 1200.0, 40.0);
        assert!((real.prior_s(&move_20, 0.0, &place) - expected).abs() < 1e-12);
        assert!((fast.prior_s(&move_20, 0.0, &place) - 0.1 * expected).abs() < 1e-12);
        assert_eq!(fast.prior_s(&move_20, -20.0, &place), 0.0);
        let capture = Step::Capture {
            theta_l: -20.0,
            index: 0,
            shutter_s: 0.5,
        };
        assert!((fast.prior_s(&capture, 0.0, &place) - 0.1 * (0.5 + 1.5)).abs() < 1e-12);
        assert!(real.expected_bracket_s() > 3.0 * 1.5);
        // An emulated camera's frame takes at least its rendering.
        let rendered = Timing {
            rendered: true,
            ..fast
        };
        let render_s = Costs::DEFAULT.frame_s_per_mpx * 3872.0 * 2592.0 / 1e6;
        assert!((rendered.prior_s(&capture, 0.0, &place) - render_s.max(0.2)).abs() < 1e-12);
    }

    #[test]
    fn processing_priors_scale_with_frames_points_and_models() {
        let timing = Timing::real();
        let place = |theta_count, theta_rank, frames| Place {
            theta_count,
            theta_rank,
            frames,
        };
        let hdr = Step::Hdr { theta_l: -20.0 };
        let two = timing.prior_s(&hdr, 0.0, &place(6, 1, 2));
        assert!(two > 0.0);
        assert!((timing.prior_s(&hdr, 0.0, &place(6, 1, 4)) - 2.0 * two).abs() < 1e-9);
        let small = timing.with_frame(968, 648);
        assert!((small.prior_s(&hdr, 0.0, &place(6, 1, 2)) - two / 16.0).abs() < 1e-9);
        // A later θL's live fits cover more points.
        let samples = Step::Samples { theta_l: -25.0 };
        assert!(
            timing.prior_s(&samples, 0.0, &place(6, 2, 2))
                > timing.prior_s(&samples, 0.0, &place(6, 1, 2))
        );
        // Every fit grows with the points of every θL.
        let auto = Step::Fit {
            model: AUTO_FIT.0.into(),
        };
        let ward = Step::Fit {
            model: "ward".into(),
        };
        // The automatic choice: on the probe's own scan (a sixteenth of the pixels,
        // every point judged) the probe's measure, a fixed part plus a part per point;
        // past the points judged per θL it no longer grows with the points.
        let costs = Costs::DEFAULT;
        let probe_points = costs.points_per_column * 968.0 * 3.0;
        assert!(
            (small.prior_s(&auto, 0.0, &place(3, 3, 2))
                - (costs.auto_s + costs.auto_s_per_point * probe_points))
                .abs()
                < 1e-9
        );
        let wide = timing.with_frame(2 * 3872, 2592);
        let judged = |t: &Timing| t.prior_s(&auto, 0.0, &place(6, 6, 2));
        assert!((judged(&wide) - judged(&timing)).abs() < 1e-9 * judged(&timing));
        assert!(small.prior_s(&auto, 0.0, &place(6, 6, 2)) < judged(&timing));
        assert!(
            (timing.prior_s(&ward, 0.0, &place(6, 6, 2))
                - 2.0 * timing.prior_s(&ward, 0.0, &place(3, 3, 2)))
            .abs()
                < 1e-9
        );
        // A samples step's extraction reads the strip rows: it follows the frame's
        // columns, not its height.
        let tall = timing.with_frame(3872, 2 * 2592);
        assert_eq!(
            tall.prior_s(&samples, 0.0, &place(6, 1, 2)),
            timing.prior_s(&samples, 0.0, &place(6, 1, 2))
        );
        assert!(Costs::DEFAULT.is_valid());
        let broken = Costs {
            hdr_s_per_mpx_frame: f64::NAN,
            ..Costs::DEFAULT
        };
        assert!(!broken.is_valid());
    }
}
