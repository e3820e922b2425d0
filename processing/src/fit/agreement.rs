//! Whether the law of propagation and the Monte Carlo of an uncertainty budget agree, and
//! where they do not, which holds and why (JCGM 101 §8: the Monte Carlo validates the
//! law of propagation; docs/ARCHITECTURE.md, "Uncertainty budget").

use serde::{Deserialize, Serialize};

use super::budget::{Budget, IntervalFrom, MonteCarlo};

/// The two agree where each end of the Monte Carlo's 95 % interval lies within this
/// fraction of the budget interval's width from the budget's (JCGM 101 §8 compares the
/// ends against a numerical tolerance; a tenth of the width is what a reader of the
/// interval would not act on).
pub const END_TOLERANCE: f64 = 0.1;

/// Which of the two intervals holds for a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Holds {
    /// They agree: either.
    Both,
    /// The budget's: the setup departs from the stated one, and the Monte Carlo draws
    /// around the values as measured.
    LawOfPropagation,
    /// The Monte Carlo's: it propagates the distributions through the fit itself, where
    /// the law of propagation linearises (or takes a source's refit ends) and adds the
    /// lines in quadrature.
    MonteCarlo,
}

/// One parameter's comparison.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Agreement {
    /// The parameter's name ([`Budget::named`]).
    pub parameter: String,
    /// The largest distance of an end of the one interval from the other's, over the
    /// budget interval's width.
    pub end_offset: f64,
    pub holds: Holds,
    /// Why, for a person.
    pub reason: String,
}

/// Each parameter's agreement of `budget` with its Monte Carlo `mc`.
pub fn compare(budget: &Budget, mc: &MonteCarlo) -> Vec<Agreement> {
    let departed = !budget.departure.is_empty();
    budget
        .named()
        .into_iter()
        .zip(mc.parameters.flat())
        .map(|((parameter, b), d)| {
            let width = (b.interval[1] - b.interval[0]).abs();
            let end_offset = if width > 0.0 {
                (d.interval[0] - b.interval[0])
                    .abs()
                    .max((d.interval[1] - b.interval[1]).abs())
                    / width
            } else {
                f64::INFINITY
            };
            let (holds, reason) = if end_offset <= END_TOLERANCE {
                (
                    Holds::Both,
                    format!(
                        "the interval ends agree within {:.0} % of the width",
                        100.0 * END_TOLERANCE
                    ),
                )
            } else if departed {
                (
                    Holds::LawOfPropagation,
                    "the residuals identify a departure of the setup: the budget's lines are \
                     taken where the world may be, the Monte Carlo draws around the values as \
                     measured only"
                        .to_string(),
                )
            } else if b.interval_from == IntervalFrom::RefitEnds {
                (
                    Holds::MonteCarlo,
                    "the parameter does not follow a source linearly over ±k u: the Monte \
                     Carlo propagates the distributions through the fit itself"
                        .to_string(),
                )
            } else {
                (
                    Holds::MonteCarlo,
                    "the sources act together beyond the sum of their lines (or the \
                     distribution is not normal): the Monte Carlo propagates them at once"
                        .to_string(),
                )
            };
            Agreement {
                parameter,
                end_offset,
                holds,
                reason,
            }
        })
        .collect()
}
