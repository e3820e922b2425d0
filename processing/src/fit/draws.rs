//! A Monte Carlo's draws (JCGM 101): the normal deviates it draws and each parameter's
//! distribution over them, with how its interval settles with the number of draws.

use serde::{Deserialize, Serialize};

/// The Monte Carlo states its intervals' convergence at halvings of its draws down to
/// this many (fewer put the 2.5 % end at fewer than 2 draws from the edge).
const CONVERGENCE_MIN_DRAWS: usize = 100;

/// A parameter's distribution over Monte Carlo draws (JCGM 101).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Distribution {
    pub mean: f64,
    /// Standard deviation: the standard uncertainty.
    pub std: f64,
    /// The probabilistically symmetric 95 % coverage interval (2.5 and 97.5 percentiles).
    pub interval: [f64; 2],
    /// How the interval settles with the number of draws: the same interval from the
    /// first N/8, N/4, N/2 and all N draws (halvings of at least 100 draws), fewest first.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub convergence: Vec<Convergence>,
}

/// A Monte Carlo interval from the first `draws` draws.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Convergence {
    pub draws: usize,
    pub interval: [f64; 2],
}

impl Distribution {
    /// The distribution of a parameter's values over the draws (at least 2), in draw order.
    pub(crate) fn of(mut values: Vec<f64>) -> Distribution {
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let std = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        let mut convergence: Vec<Convergence> =
            std::iter::successors(Some(values.len()), |&d| Some(d / 2))
                .take_while(|&d| d >= CONVERGENCE_MIN_DRAWS)
                .take(4)
                .map(|d| Convergence {
                    draws: d,
                    interval: coverage_interval(&mut values[..d].to_vec()),
                })
                .collect();
        convergence.reverse();
        Distribution {
            mean,
            std,
            interval: coverage_interval(&mut values),
            convergence,
        }
    }
}

/// The probabilistically symmetric 95 % coverage interval of `values` (sorted in place).
fn coverage_interval(values: &mut [f64]) -> [f64; 2] {
    values.sort_by(f64::total_cmp);
    let last = values.len() - 1;
    let at = |q: f64| values[((q * last as f64).round() as usize).min(last)];
    [at(0.025), at(0.975)]
}

/// A normal deviate stream (splitmix64, Box–Muller), reproducible from its seed.
pub(crate) struct Normal {
    state: u64,
    spare: Option<f64>,
}

impl Normal {
    pub(crate) fn new(seed: u64) -> Self {
        Normal {
            state: seed,
            spare: None,
        }
    }

    fn uniform(&mut self) -> f64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    pub(crate) fn next(&mut self) -> f64 {
        if let Some(v) = self.spare.take() {
            return v;
        }
        let (u1, u2) = (self.uniform(), self.uniform());
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (2.0 * std::f64::consts::PI * u2).sin_cos();
        self.spare = Some(r * s);
        r * c
    }
}
