//! What extraction drops and why: whole columns (off the cylinder, unlit, grazing, no
//! usable channel) and single values (a channel of a column: saturated, underexposed,
//! dark white reference).

use super::strip::StripValue;
use crate::hdr::{SATURATED, UNDEREXPOSED};

/// What was dropped. Columns count once, in the first reason that applies; values (one
/// channel of one kept or dropped column) count per channel R, G, B, in the first
/// reason that applies to that channel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DropCounts {
    /// Columns: a strip pixel misses the cylinder, or is not lit (|θi| ≥ 90°).
    pub off_cylinder: usize,
    /// Columns: |θi| or |θr| beyond the grazing limit.
    pub grazing: usize,
    /// Columns whose three channels were all dropped (counted below too).
    pub no_channel: usize,
    /// Values: a pixel of the sample or white strip is clipped in every exposure.
    pub saturated: [usize; 3],
    /// Values: a pixel of the sample strip is below the noise floor in every exposure.
    pub underexposed: [usize; 3],
    /// Values: the white strip is too dark (or black in every exposure).
    pub dark_white: [usize; 3],
}

impl DropCounts {
    /// Columns dropped.
    pub fn total(&self) -> usize {
        self.off_cylinder + self.grazing + self.no_channel
    }

    /// Values dropped in channel `c` (R, G, B = 0, 1, 2), whatever the reason.
    pub fn values(&self, c: usize) -> usize {
        self.saturated[c] + self.underexposed[c] + self.dark_white[c]
    }

    /// The reason most columns were dropped for, with its count (`None` if none was):
    /// among the columns on the cylinder (grazing, no usable channel) when some were,
    /// else off the cylinder (the background beside the strips is always dropped, so
    /// it explains nothing when columns of the cylinder were seen). Columns with no
    /// usable channel are named for the reason most of their values were dropped for.
    pub fn dominant(&self) -> Option<(&'static str, usize)> {
        let sum = |v: [usize; 3]| v.iter().sum::<usize>();
        let no_channel = [
            ("no usable channel (mostly saturated)", sum(self.saturated)),
            (
                "no usable channel (mostly underexposed)",
                sum(self.underexposed),
            ),
            (
                "no usable channel (mostly a dark white reference)",
                sum(self.dark_white),
            ),
        ]
        .into_iter()
        .max_by_key(|(_, n)| *n)
        .map_or("no usable channel", |(reason, _)| reason);
        [("grazing", self.grazing), (no_channel, self.no_channel)]
            .into_iter()
            .filter(|(_, n)| *n > 0)
            .max_by_key(|(_, n)| *n)
            .or(Some(("off the cylinder or unlit", self.off_cylinder)).filter(|(_, n)| *n > 0))
    }

    /// Why an extraction gave no sample: the dominant reason and every count.
    pub fn explain_empty(&self) -> String {
        let rgb = |v: [usize; 3]| format!("{}/{}/{}", v[0], v[1], v[2]);
        match self.dominant() {
            Some((reason, n)) => format!(
                "no samples: all {} columns were dropped, {n} as {reason} \
                 ({} grazing, {} with no usable channel, {} off the cylinder or unlit; \
                 values dropped R/G/B: {} saturated, {} underexposed, {} dark white)",
                self.total(),
                self.grazing,
                self.no_channel,
                self.off_cylinder,
                rgb(self.saturated),
                rgb(self.underexposed),
                rgb(self.dark_white),
            ),
            None => "no samples: no column of the captures was on the strips".to_owned(),
        }
    }

    pub(super) fn add(&mut self, other: &DropCounts) {
        self.off_cylinder += other.off_cylinder;
        self.grazing += other.grazing;
        self.no_channel += other.no_channel;
        for c in 0..3 {
            self.saturated[c] += other.saturated[c];
            self.underexposed[c] += other.underexposed[c];
            self.dark_white[c] += other.dark_white[c];
        }
    }
}

/// Why one value (a channel of a column) is dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum DropReason {
    Saturated,
    Underexposed,
    DarkWhite,
}

impl DropReason {
    /// Why channel `c` of a column with these strips is dropped, if it is; `threshold`
    /// is the channel's too-dark white level.
    pub(super) fn of(
        sample: &StripValue,
        white: &StripValue,
        c: usize,
        threshold: f64,
    ) -> Option<Self> {
        if (sample.flags[c] | white.flags[c]) & SATURATED != 0 {
            Some(Self::Saturated)
        } else if white.flags[c] & UNDEREXPOSED != 0
            || !(white.rgb[c] > threshold && white.rgb[c] > 0.0)
        {
            Some(Self::DarkWhite)
        } else if sample.flags[c] & UNDEREXPOSED != 0 {
            Some(Self::Underexposed)
        } else {
            None
        }
    }
}

impl DropCounts {
    pub(super) fn count(&mut self, reason: DropReason, c: usize) {
        let counts = match reason {
            DropReason::Saturated => &mut self.saturated,
            DropReason::Underexposed => &mut self.underexposed,
            DropReason::DarkWhite => &mut self.dark_white,
        };
        counts[c] += 1;
    }
}
