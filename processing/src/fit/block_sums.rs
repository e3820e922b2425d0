//! The sums of the sandwich over a fit's points (`super::uncertainty`), a block of points
//! at a time: the block's per-point terms are laid side by side, then each total adds
//! them in [`LANES`] partial sums, so that the additions run side by side in vector
//! registers (a fixed order: the same sums on every machine). On a processor with AVX2
//! and FMA the adding is compiled for them and chosen at run time (no operation fused
//! that the portable code does not fuse: the same values).

#[cfg(target_arch = "x86_64")]
use crate::simd::avx2_fma;

/// The most parameters a fit has: Kd, Ks, Ks_90 and m per channel.
pub(super) const MAX_PARAMETERS: usize = 12;

/// A symmetric P × P sum on the stack; only i ≤ j is accumulated.
pub(super) type Square = [[f64; MAX_PARAMETERS]; MAX_PARAMETERS];

/// Points in a block.
pub(super) const BLOCK: usize = 64;

/// Partial sums of each total over a block.
const LANES: usize = 8;

/// The columns a row of a channel's Jacobian can be nonzero at, ascending, and how many.
pub(super) type Columns = ([usize; 4], usize);

/// A block's per-point terms side by side (zero past its points): J_p's value per
/// channel and column of its [`Columns`], g_p per parameter, and 1/‖r_p‖.
pub(super) struct Block {
    pub rows: [[[f64; BLOCK]; 4]; 3],
    pub gradient: [[f64; BLOCK]; MAX_PARAMETERS],
    pub inverse: [f64; BLOCK],
}

impl Block {
    pub fn zeroed() -> Box<Block> {
        Box::new(Block {
            rows: [[[0.0; BLOCK]; 4]; 3],
            gradient: [[0.0; BLOCK]; MAX_PARAMETERS],
            inverse: [0.0; BLOCK],
        })
    }

    /// Readies the block for `len` points' terms among `p` parameters, which the caller
    /// then writes in full (rows and 1/‖r‖) or adds to (g): g zero, and every term
    /// past the points zero.
    pub fn start(&mut self, len: usize, p: usize) {
        for g in &mut self.gradient[..p] {
            g.fill(0.0);
        }
        if len < BLOCK {
            for row in self.rows.iter_mut().flatten() {
                row[len..].fill(0.0);
            }
            self.inverse[len..].fill(0.0);
        }
    }
}

/// A = Σ_p (J_pᵀ J_p − g_p g_pᵀ)/‖r_p‖ (its upper triangle), Σ_p g_p g_pᵀ and Σ_p g_p.
pub(super) struct Totals {
    pub hessian: Square,
    pub spread: Square,
    pub descent: [f64; MAX_PARAMETERS],
}

impl Totals {
    pub fn zero() -> Self {
        Totals {
            hessian: [[0.0; MAX_PARAMETERS]; MAX_PARAMETERS],
            spread: [[0.0; MAX_PARAMETERS]; MAX_PARAMETERS],
            descent: [0.0; MAX_PARAMETERS],
        }
    }

    /// Adds `block`'s points, whose rows lie at `columns` (per channel) among `p`
    /// parameters; Σ g_p g_pᵀ only `with_spread`.
    pub fn add(&mut self, block: &Block, columns: &[Columns; 3], p: usize, with_spread: bool) {
        #[cfg(target_arch = "x86_64")]
        if avx2_fma() {
            // SAFETY: the processor has AVX2 and FMA, checked just above.
            return unsafe { add_avx2(self, block, columns, p, with_spread) };
        }
        add_portable(self, block, columns, p, with_spread);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn add_avx2(
    totals: &mut Totals,
    block: &Block,
    columns: &[Columns; 3],
    p: usize,
    with_spread: bool,
) {
    add_portable(totals, block, columns, p, with_spread);
}

#[inline(always)]
fn add_portable(
    totals: &mut Totals,
    block: &Block,
    columns: &[Columns; 3],
    p: usize,
    with_spread: bool,
) {
    let inverse = &block.inverse;
    for (rows, (columns, width)) in block.rows.iter().zip(columns) {
        for a in 0..*width {
            for b in a..*width {
                totals.hessian[columns[a]][columns[b]] += sum3(&rows[a], inverse, &rows[b]);
            }
        }
    }
    let g = &block.gradient;
    for i in 0..p {
        totals.descent[i] += sum1(&g[i]);
        for j in i..p {
            totals.hessian[i][j] -= sum3(&g[i], inverse, &g[j]);
        }
        if with_spread {
            for j in i..p {
                totals.spread[i][j] += sum2(&g[i], &g[j]);
            }
        }
    }
}

/// Σ_k a_k·w_k·b_k over a block.
#[inline(always)]
fn sum3(a: &[f64; BLOCK], w: &[f64; BLOCK], b: &[f64; BLOCK]) -> f64 {
    let mut lanes = [0.0; LANES];
    for ((a, w), b) in a
        .chunks_exact(LANES)
        .zip(w.chunks_exact(LANES))
        .zip(b.chunks_exact(LANES))
    {
        for l in 0..LANES {
            lanes[l] += a[l] * w[l] * b[l];
        }
    }
    lanes.iter().sum()
}

/// Σ_k a_k·b_k over a block.
#[inline(always)]
fn sum2(a: &[f64; BLOCK], b: &[f64; BLOCK]) -> f64 {
    let mut lanes = [0.0; LANES];
    for (a, b) in a.chunks_exact(LANES).zip(b.chunks_exact(LANES)) {
        for l in 0..LANES {
            lanes[l] += a[l] * b[l];
        }
    }
    lanes.iter().sum()
}

/// Σ_k a_k over a block.
#[inline(always)]
fn sum1(a: &[f64; BLOCK]) -> f64 {
    let mut lanes = [0.0; LANES];
    for a in a.chunks_exact(LANES) {
        for l in 0..LANES {
            lanes[l] += a[l];
        }
    }
    lanes.iter().sum()
}
