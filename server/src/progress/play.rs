//! The lanes played forward from now (server/src/daemon.md, "Time left"), under the
//! daemon's own rules: the hardware lane's steps one after the other, a bracket begun
//! (its move) only while fewer than `max_backlog` captured brackets await processing;
//! the processing lane's steps in journal order, each once the steps before it are
//! done, an HDR map and the automatic choice beside them (one of each at a time, once
//! the steps they need are done); with nothing else to run, the lane waits for the
//! step beside it to end if one runs (starting nothing meanwhile), else decodes the
//! frames captured for an HDR map not begun ahead of it. The processing work
//! under way shares the cores equally, and has a share of them while an emulated
//! camera renders a frame. The play runs from event to event (a step ends, a frame's
//! rendering ends, the frames captured so far are decoded) and says when the last
//! step ends.

use crate::plan::{Lane, Step};
use crate::store::brackets_behind;

/// A step not done, as the play runs it.
#[derive(Debug, Clone)]
pub(super) struct Work {
    pub step: Step,
    /// Seconds it still takes: wall-clock on the hardware lane, with the cores to
    /// itself on the processing lane.
    pub left_s: f64,
    /// Of a hardware step: the seconds at its start (from now, if under way) while an
    /// emulated camera renders on the cores.
    pub render_s: f64,
    /// Whether it is under way now.
    pub started: bool,
    /// Of an HDR step: the seconds of its work that decoding one frame is, which the
    /// lane may do ahead of it once the frame is captured; and the frames of its
    /// bracket captured before now.
    pub decode_s_per_frame: f64,
    pub captured: usize,
}

/// The rules the lanes run by and the cores they share.
#[derive(Debug, Clone, Copy)]
pub(super) struct Rules {
    /// Captured brackets awaiting processing at which the arm waits.
    pub max_backlog: usize,
    /// The processing lane's share of the cores while a frame renders.
    pub share_while_rendering: f64,
}

/// Where a step stands in the play.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Run {
    Waiting,
    /// On the hardware lane or in the processing lane's foreground.
    Lane,
    /// Beside the processing lane's steps.
    Beside,
    Done,
}

/// Seconds below which work counts as done (float residue of the steps' sums).
const EPS_S: f64 = 1e-9;

/// Seconds from now until every step of `work` (in journal order) is done.
pub(super) fn play(work: &[Work], rules: &Rules) -> f64 {
    let mut play = Play::new(work, rules);
    // Every event ends a step, a rendering or the frames decodable: a bound the play
    // never reaches unless the steps cannot run (then the rest is counted in turn).
    let bound = 4 * work.len() + 16;
    for _ in 0..bound {
        play.start_steps();
        if play.run.iter().all(|r| *r == Run::Done) {
            return play.t;
        }
        if !play.advance() {
            break;
        }
    }
    let rest: f64 = (0..work.len())
        .filter(|&i| play.run[i] != Run::Done)
        .map(|i| play.work[i].left_s)
        .sum();
    play.t + rest
}

struct Play {
    work: Vec<Work>,
    run: Vec<Run>,
    rules: Rules,
    /// Seconds from now.
    t: f64,
    /// Of each HDR step not begun: the seconds of it decoded ahead.
    decoded_s: Vec<f64>,
    /// The HDR step whose frames the lane decodes ahead, if it does.
    decoding: Option<usize>,
    /// Whether the processing lane waits for a step beside the others to end (it
    /// starts nothing meanwhile).
    waits_for_beside: bool,
}

impl Play {
    fn new(work: &[Work], rules: &Rules) -> Self {
        let run = work
            .iter()
            .map(|w| match (w.started, w.step.lane(), w.step.runs_beside()) {
                (false, _, _) => Run::Waiting,
                (true, Lane::Processing, true) => Run::Beside,
                (true, _, _) => Run::Lane,
            })
            .collect();
        Play {
            work: work.to_vec(),
            run,
            rules: *rules,
            t: 0.0,
            decoded_s: vec![0.0; work.len()],
            decoding: None,
            waits_for_beside: false,
        }
    }

    fn not_done(&self, i: usize) -> bool {
        self.run[i] != Run::Done
    }

    /// θL whose bracket is captured but not processed, as the hardware lane counts them.
    fn backlog(&self) -> usize {
        brackets_behind(
            self.work
                .iter()
                .zip(&self.run)
                .map(|(w, r)| (&w.step, *r == Run::Done)),
        )
    }

    /// Starts what the lanes would start now.
    fn start_steps(&mut self) {
        self.decoding = None;
        // The hardware lane's next step, unless it is a move while the backlog is full.
        let next_hw = (0..self.work.len())
            .find(|&i| self.not_done(i) && self.work[i].step.lane() == Lane::Hardware);
        if let Some(i) = next_hw {
            let held = matches!(self.work[i].step, Step::Move { .. })
                && self.backlog() >= self.rules.max_backlog;
            if self.run[i] == Run::Waiting && !held {
                self.run[i] = Run::Lane;
            }
        }
        if self.waits_for_beside {
            return;
        }
        // Beside the others: the first step waiting of each kind that runs beside them,
        // unless one of its kind runs, once every step before it not done is a
        // processing step it does not need (a later one of the kind waits for the same
        // steps and more). One pass, so that a long sweep's play stays linear per event.
        let mut busy = Vec::new();
        let mut first = Vec::new();
        for (i, w) in self.work.iter().enumerate() {
            if !w.step.runs_beside() || w.step.lane() != Lane::Processing {
                continue;
            }
            let kind = std::mem::discriminant(&w.step);
            match self.run[i] {
                Run::Beside => busy.push(kind),
                Run::Waiting if !first.iter().any(|&(k, _)| k == kind) => first.push((kind, i)),
                _ => {}
            }
        }
        for (kind, i) in first {
            let step = &self.work[i].step;
            let ready = (0..i).filter(|&j| self.not_done(j)).all(|j| {
                self.work[j].step.lane() == Lane::Processing && !step.needs(&self.work[j].step)
            });
            if ready && !busy.contains(&kind) {
                self.begin(i, Run::Beside);
            }
        }
        // The lane's own: the first step not done and not beside, if a processing step
        // that does not run beside the others; else, with a step beside the others
        // under way, the lane waits for it to end; else it decodes ahead.
        let lane_busy = (0..self.work.len())
            .any(|i| self.run[i] == Run::Lane && self.work[i].step.lane() == Lane::Processing);
        if lane_busy {
            return;
        }
        let first = (0..self.work.len()).find(|&i| self.not_done(i) && self.run[i] != Run::Beside);
        match first {
            Some(i)
                if self.work[i].step.lane() == Lane::Processing
                    && !self.work[i].step.runs_beside() =>
            {
                self.begin(i, Run::Lane);
            }
            _ if self.run.contains(&Run::Beside) => self.waits_for_beside = true,
            _ => self.decoding = (0..self.work.len()).find(|&i| self.decodable_s(i) > EPS_S),
        }
    }

    /// Begins step `i`; an HDR step without what was decoded ahead of it.
    fn begin(&mut self, i: usize, run: Run) {
        self.run[i] = run;
        self.work[i].left_s = (self.work[i].left_s - self.decoded_s[i]).max(0.0);
    }

    /// Seconds of HDR step `i` (not begun) that may still be decoded ahead now.
    fn decodable_s(&self, i: usize) -> f64 {
        let w = &self.work[i];
        if self.run[i] != Run::Waiting || !matches!(w.step, Step::Hdr { .. }) {
            return 0.0;
        }
        let frames_s = (w.captured as f64 * w.decode_s_per_frame).min(w.left_s);
        frames_s - self.decoded_s[i]
    }

    /// Runs the play to its next event; false if nothing runs (the steps left cannot).
    fn advance(&mut self) -> bool {
        let rendering =
            (0..self.work.len()).any(|i| self.run[i] == Run::Lane && self.work[i].render_s > EPS_S);
        let processing: Vec<usize> = (0..self.work.len())
            .filter(|&i| {
                matches!(self.run[i], Run::Lane | Run::Beside)
                    && self.work[i].step.lane() == Lane::Processing
            })
            .collect();
        let sharing = processing.len() + usize::from(self.decoding.is_some());
        let rate = if rendering {
            self.rules.share_while_rendering
        } else {
            1.0
        } / sharing.max(1) as f64;
        let hardware = (0..self.work.len())
            .find(|&i| self.run[i] == Run::Lane && self.work[i].step.lane() == Lane::Hardware);
        // The next event.
        let mut dt = f64::INFINITY;
        if let Some(i) = hardware {
            let w = &self.work[i];
            dt = dt.min(if w.render_s > EPS_S {
                w.render_s.min(w.left_s)
            } else {
                w.left_s
            });
        }
        for &i in &processing {
            dt = dt.min(self.work[i].left_s / rate);
        }
        if let Some(i) = self.decoding {
            dt = dt.min(self.decodable_s(i) / rate);
        }
        if !dt.is_finite() {
            return false;
        }
        let dt = dt.max(0.0);
        self.t += dt;
        if let Some(i) = hardware {
            let w = &mut self.work[i];
            w.left_s -= dt;
            w.render_s = (w.render_s - dt).max(0.0);
            if w.left_s <= EPS_S {
                self.finish(i);
            }
        }
        for &i in &processing {
            self.work[i].left_s -= dt * rate;
            if self.work[i].left_s <= EPS_S {
                self.finish(i);
            }
        }
        if let Some(i) = self.decoding {
            self.decoded_s[i] += dt * rate;
        }
        true
    }

    /// Ends step `i`; a capture's frame becomes one its HDR step may decode ahead.
    fn finish(&mut self, i: usize) {
        if self.run[i] == Run::Beside {
            self.waits_for_beside = false;
        }
        self.run[i] = Run::Done;
        self.work[i].left_s = 0.0;
        if let Step::Capture { theta_l, .. } = self.work[i].step {
            let hdr = self
                .work
                .iter()
                .position(|w| matches!(w.step, Step::Hdr { theta_l: t } if t == theta_l));
            if let Some(h) = hdr {
                self.work[h].captured += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn work(step: Step, left_s: f64) -> Work {
        Work {
            step,
            left_s,
            render_s: 0.0,
            started: false,
            decode_s_per_frame: 0.0,
            captured: 0,
        }
    }

    const RULES: Rules = Rules {
        max_backlog: 2,
        share_while_rendering: 0.25,
    };

    fn bracket(theta_l: f64, capture_s: f64, samples_s: f64, hdr_s: f64) -> Vec<Work> {
        vec![
            work(Step::Move { theta_l }, 1.0),
            work(
                Step::Capture {
                    theta_l,
                    index: 0,
                    shutter_s: 0.1,
                },
                capture_s,
            ),
            work(Step::Samples { theta_l }, samples_s),
            work(Step::Hdr { theta_l }, hdr_s),
        ]
    }

    #[test]
    fn processing_runs_beside_the_hardware_and_shares_the_cores() {
        // Each bracket: move 1 s, capture 1.5 s, its samples 1 s and map 2 s.
        let mut steps = bracket(-20.0, 1.5, 1.0, 2.0);
        steps.extend(bracket(-30.0, 1.5, 1.0, 2.0));
        // The first bracket's samples and map share the cores from 2.5 s, beside the
        // second bracket's hardware (to 5 s): the samples end at 4.5 s, the map half
        // done. With nothing else ready then, the lane waits for the map, which ends
        // alone at 5.5 s; the second bracket's samples and map then share the cores
        // to 7.5 s, and the map runs alone to 8.5 s.
        assert!((play(&steps, &RULES) - 8.5).abs() < 1e-9);
    }

    #[test]
    fn the_arm_waits_while_the_backlog_is_full() {
        // Slow processing: 10 s per bracket. With a backlog of one bracket the second
        // move waits for the first bracket's processing.
        let mut steps = bracket(-20.0, 1.0, 0.0, 10.0);
        steps.extend(bracket(-30.0, 1.0, 0.0, 10.0));
        let one = Rules {
            max_backlog: 1,
            ..RULES
        };
        // Captured at 2 s, processed at 12 s; the second bracket captured at 14 s,
        // processed at 24 s.
        assert!((play(&steps, &one) - 24.0).abs() < 1e-9);
        // With two, the arm goes on: the second bracket is processed after the first.
        assert!((play(&steps, &RULES) - 22.0).abs() < 1e-9);
    }

    #[test]
    fn rendering_leaves_processing_its_share_and_frames_decode_ahead() {
        let rendered = |mut w: Work| {
            w.render_s = w.left_s;
            w
        };
        let steps = vec![
            work(Step::Hdr { theta_l: -25.0 }, 4.0),
            rendered(work(Step::Move { theta_l: -30.0 }, 4.0)),
        ];
        let mut started = steps.clone();
        started[0].started = true;
        // 4 s of rendering at a quarter: 1 s of the map done, 3 s after.
        assert!((play(&started, &RULES) - 7.0).abs() < 1e-9);
        // Frames decoded ahead: while the lane has nothing to run, the captured
        // frame's decoding (1 s) is done before the map's step begins.
        let mut steps = bracket(-20.0, 1.0, 0.0, 3.0);
        steps[3].decode_s_per_frame = 1.0;
        steps.insert(
            2,
            work(
                Step::Capture {
                    theta_l: -20.0,
                    index: 1,
                    shutter_s: 0.1,
                },
                2.0,
            ),
        );
        // Move 1 s, capture 1 s, capture 2 s; the first frame decoded from 2 s to 3 s;
        // the map's 2 s left run from 4 s.
        assert!((play(&steps, &RULES) - 6.0).abs() < 1e-9);
    }
}
