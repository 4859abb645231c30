//! f32 building blocks of the fast networks: packed linear layers evaluated for many rows at
//! once, an LSTM cell with the spatial embedding folded into its input weights, and the split
//! pooling module. Every kernel is generic over the instruction set ([`Simd`]) and runs through
//! [`Isa::run`], so one build carries a portable, an AVX2 and an AVX-512 version of each.
//!
//! Weights are repacked at load time into blocks of one vector's lanes (16 f32 or 8 f64)
//! stored input-major (`[n_blocks][in][lanes]`). A layer applied to `m` rows (agents, or agent
//! pairs) is a small matrix product evaluated in register tiles of `TILE_ROWS` rows ×
//! `TILE_BLOCKS` output blocks: per input `k`, one load of each weight block is reused for every
//! row of the tile (one broadcast multiply-add each). The one tile ([`tile`]) serves both
//! precisions of the sums ([`Elem`]: f32, or f64 with the f32 inputs widened exactly). Every
//! output still sums its terms in input order, starting from its bias, so the result of a row
//! does not depend on the tiling, the number of rows, nor (between the fused paths) the vector
//! width: see [`simd`](crate::simd).

use crate::simd::{Elem, Isa, Kernel, LANES, Simd, SimdPath, max_nan};

/// 16 output lanes of one packed f32 weight row.
type Block = [f32; LANES];

/// Packs a row-major `[out, in]` matrix into `[ceil(out/lanes)][in]` blocks of
/// [`Elem::LANES`] lanes in precision `E` (widened exactly), zero padded.
fn pack<E: Elem>(w: &[f32], out_dim: usize, in_dim: usize) -> Vec<E::Block> {
    let nblk = out_dim.div_ceil(E::LANES);
    let mut p = vec![E::Block::default(); nblk * in_dim];
    for o in 0..out_dim {
        let (blk, l) = (o / E::LANES, o % E::LANES);
        for k in 0..in_dim {
            p[blk * in_dim + k].as_mut()[l] = E::widen(w[o * in_dim + k]);
        }
    }
    p
}

/// `v` zero padded to whole blocks of precision `E`.
fn pad<E: Elem>(v: &[f32]) -> Vec<E::Block> {
    pack::<E>(v, v.len(), 1)
}

/// The 16-lane blocks of `x` (whose length must be a multiple of 16).
#[inline(always)]
fn blocks(x: &[f32]) -> &[Block] {
    let (b, rest) = x.as_chunks::<LANES>();
    debug_assert!(rest.is_empty());
    b
}

/// Mutable 16-lane blocks of `x` (whose length must be a multiple of 16).
#[inline(always)]
fn blocks_mut(x: &mut [f32]) -> &mut [Block] {
    let (b, rest) = x.as_chunks_mut::<LANES>();
    debug_assert!(rest.is_empty());
    b
}

/// Multiply-adds executed by the kernels on this thread (test builds only), to check the
/// analytical counts of [`cost`](crate::cost).
#[cfg(test)]
pub(crate) mod counter {
    use std::cell::Cell;

    thread_local! {
        static MACS: Cell<u64> = const { Cell::new(0) };
    }

    /// Adds `n` multiply-adds.
    pub(crate) fn add(n: usize) {
        MACS.with(|c| c.set(c.get() + n as u64));
    }

    /// Returns the count and resets it.
    pub(crate) fn take() -> u64 {
        MACS.with(|c| c.replace(0))
    }
}

/// Records `n` multiply-adds (a no-op outside test builds).
#[inline(always)]
fn count_macs(n: usize) {
    #[cfg(test)]
    counter::add(n);
    #[cfg(not(test))]
    let _ = n;
}

/// Calls `$f::<$T.., MB, OB>($args)` for the runtime tile shape `($mb, $ob)`,
/// `1 <= $mb <= 8`, `1 <= $ob <= 2`.
macro_rules! by_tile {
    ($mb:expr, $ob:expr, $f:ident::<$($T:ty),+>($($arg:expr),* $(,)?)) => {
        match ($mb, $ob) {
            (1, 1) => $f::<$($T),+, 1, 1>($($arg),*),
            (2, 1) => $f::<$($T),+, 2, 1>($($arg),*),
            (3, 1) => $f::<$($T),+, 3, 1>($($arg),*),
            (4, 1) => $f::<$($T),+, 4, 1>($($arg),*),
            (5, 1) => $f::<$($T),+, 5, 1>($($arg),*),
            (6, 1) => $f::<$($T),+, 6, 1>($($arg),*),
            (7, 1) => $f::<$($T),+, 7, 1>($($arg),*),
            (8, 1) => $f::<$($T),+, 8, 1>($($arg),*),
            (1, 2) => $f::<$($T),+, 1, 2>($($arg),*),
            (2, 2) => $f::<$($T),+, 2, 2>($($arg),*),
            (3, 2) => $f::<$($T),+, 3, 2>($($arg),*),
            (4, 2) => $f::<$($T),+, 4, 2>($($arg),*),
            (5, 2) => $f::<$($T),+, 5, 2>($($arg),*),
            (6, 2) => $f::<$($T),+, 6, 2>($($arg),*),
            (7, 2) => $f::<$($T),+, 7, 2>($($arg),*),
            (8, 2) => $f::<$($T),+, 8, 2>($($arg),*),
            _ => unreachable!("tile shapes are at most 8 rows x 2 blocks"),
        }
    };
}

/// Largest `TILE_ROWS` of any path (scratch sizing).
pub(crate) const MAX_TILE_ROWS: usize = 8;

/// The register tile, in precision `E`: rows `r0..r0+MB` of `x` (row `r` is
/// `x[r*ldx..][..k]`, f32, widened exactly) times output blocks `blk0..blk0+OB` of the packed
/// `w` (`[n_blocks][k]` blocks), accumulated onto `init` in input order.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn tile<S: Simd, E: Elem, const MB: usize, const OB: usize>(
    s: S,
    w: &[E::Block],
    k: usize,
    blk0: usize,
    x: &[f32],
    ldx: usize,
    r0: usize,
    init: [E::V<S>; OB],
) -> [[E::V<S>; OB]; MB] {
    // Slices of length exactly `k` (`[..k]`), so that the loop below needs no bounds checks.
    let mut ws: [&[E::Block]; OB] = [&[]; OB];
    for (o, wo) in ws.iter_mut().enumerate() {
        *wo = &w[(blk0 + o) * k..][..k];
    }
    let mut xs: [&[f32]; MB] = [&[]; MB];
    for (r, xr) in xs.iter_mut().enumerate() {
        *xr = &x[(r0 + r) * ldx..][..k];
    }
    let mut acc = [init; MB];
    for kk in 0..k {
        let mut wv = init;
        for o in 0..OB {
            wv[o] = E::load(s, &ws[o][kk]);
        }
        for r in 0..MB {
            let xv = E::splat(s, xs[r][kk]);
            for o in 0..OB {
                acc[r][o] = E::mul_add(s, xv, wv[o], acc[r][o]);
            }
        }
    }
    acc
}

/// Precision of the sums of a [`Dense`] layer (its inputs and outputs are f32 either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Accumulate {
    /// f32 accumulators (16 lanes per vector).
    F32,
    /// f64 accumulators (8 lanes per vector; weights widened at load time, inputs widened
    /// exactly), rounded to f32 once per output.
    F64,
}

/// Weights `[n_blocks][in]` and bias `[n_blocks]` of a [`Dense`] layer packed in blocks of
/// precision `E`.
#[derive(Debug, Clone)]
struct Packed<E: Elem> {
    w: Vec<E::Block>,
    b: Vec<E::Block>,
}

impl<E: Elem> Packed<E> {
    /// Packs the row-major `[out, in]` weight `w` and the `[out]` bias `b`.
    fn new(w: &[f32], b: &[f32], out_dim: usize, in_dim: usize) -> Self {
        Self {
            w: pack::<E>(w, out_dim, in_dim),
            b: pad::<E>(b),
        }
    }
}

/// The packed weights of a [`Dense`] layer, in the precision of its sums.
#[derive(Debug, Clone)]
enum Weights {
    /// Blocks of 16 f32 lanes.
    F32(Packed<f32>),
    /// Blocks of 8 f64 lanes.
    F64(Packed<f64>),
}

/// `y = W x + b` with `W` `[out, in]`, repacked for vectorised evaluation, summing in the
/// chosen [`Accumulate`] precision (zero padded to whole blocks).
#[derive(Debug, Clone)]
pub(crate) struct Dense {
    in_dim: usize,
    out_dim: usize,
    packed: Weights,
}

impl Dense {
    /// From a row-major `[out, in]` weight and an `[out]` bias.
    pub(crate) fn new(
        w: &[f32],
        b: &[f32],
        out_dim: usize,
        in_dim: usize,
        acc: Accumulate,
    ) -> Self {
        debug_assert_eq!(w.len(), out_dim * in_dim);
        debug_assert_eq!(b.len(), out_dim);
        let packed = match acc {
            Accumulate::F32 => Weights::F32(Packed::new(w, b, out_dim, in_dim)),
            Accumulate::F64 => Weights::F64(Packed::new(w, b, out_dim, in_dim)),
        };
        Self {
            in_dim,
            out_dim,
            packed,
        }
    }

    /// Output size.
    pub(crate) fn out_dim(&self) -> usize {
        self.out_dim
    }

    /// `y[r*ldy..][..out] = W x[r*ldx..][..in] + b` for the `m` rows `r < m`, ReLU applied
    /// when `relu`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn rows(
        &self,
        isa: Isa,
        x: &[f32],
        ldx: usize,
        m: usize,
        y: &mut [f32],
        ldy: usize,
        relu: bool,
    ) {
        isa.run(DenseRows {
            d: self,
            x,
            ldx,
            m,
            y,
            ldy,
            relu,
        });
    }
}

struct DenseRows<'a> {
    d: &'a Dense,
    x: &'a [f32],
    ldx: usize,
    m: usize,
    y: &'a mut [f32],
    ldy: usize,
    relu: bool,
}

impl Kernel for DenseRows<'_> {
    type Out = ();
    #[inline(always)]
    fn run<S: Simd>(self, s: S) {
        dense_rows(
            s, self.d, self.x, self.ldx, self.m, self.y, self.ldy, self.relu,
        );
    }
}

/// [`Dense::rows`] on instruction set `s`, in the precision of `d`'s sums.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn dense_rows<S: Simd>(
    s: S,
    d: &Dense,
    x: &[f32],
    ldx: usize,
    m: usize,
    y: &mut [f32],
    ldy: usize,
    relu: bool,
) {
    count_macs(m * d.in_dim * d.out_dim);
    let nblk = match &d.packed {
        Weights::F32(p) => p.b.len(),
        Weights::F64(p) => p.b.len(),
    };
    let mut r = 0;
    while r < m {
        let mb = (m - r).min(S::TILE_ROWS);
        let mut blk = 0;
        while blk < nblk {
            let ob = (nblk - blk).min(S::TILE_BLOCKS);
            match &d.packed {
                Weights::F32(p) => by_tile!(
                    mb,
                    ob,
                    dense_tile::<S, f32>(s, d, p, x, ldx, r, blk, y, ldy, relu)
                ),
                Weights::F64(p) => by_tile!(
                    mb,
                    ob,
                    dense_tile::<S, f64>(s, d, p, x, ldx, r, blk, y, ldy, relu)
                ),
            }
            blk += ob;
        }
        r += mb;
    }
}

/// One register tile of [`Dense::rows`]: rows `r0..r0+MB`, output blocks `blk0..blk0+OB`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn dense_tile<S: Simd, E: Elem, const MB: usize, const OB: usize>(
    s: S,
    d: &Dense,
    p: &Packed<E>,
    x: &[f32],
    ldx: usize,
    r0: usize,
    blk0: usize,
    y: &mut [f32],
    ldy: usize,
    relu: bool,
) {
    let mut init = [E::splat(s, 0.0); OB];
    for (o, v) in init.iter_mut().enumerate() {
        *v = E::load(s, &p.b[blk0 + o]);
    }
    let acc = tile::<S, E, MB, OB>(s, &p.w, d.in_dim, blk0, x, ldx, r0, init);
    for (r, row) in acc.into_iter().enumerate() {
        for (o, v) in row.into_iter().enumerate() {
            let lane0 = (blk0 + o) * E::LANES;
            let start = (r0 + r) * ldy + lane0;
            let n = (d.out_dim - lane0).min(E::LANES);
            E::store_f32(s, v, relu, &mut y[start..start + n]);
        }
    }
}

/// Scalar ReLU `max(x, 0)` that keeps NaN (see [`max_nan`](crate::simd::max_nan)): the
/// same rule, and the same bits, as the vector ReLU `Simd::max(x, 0)` of the kernels.
#[inline(always)]
pub(crate) fn relu_nan(x: f32) -> f32 {
    max_nan(x, 0.0)
}

/// `e^x` in f32 for the activations, branch-free so that loops over slices vectorise:
/// range reduction `x = n ln2 + r` (ln 2 split in two for exactness), a degree-7 polynomial
/// for `e^r` on |r| ≤ ln2/2, and `2^n` built from the exponent bits. Relative error
/// ≈ 1 ulp over the clamped range [-87, 88] (checked in the tests). Multiply-adds round as
/// the path's [`Simd::fma1`].
#[inline(always)]
fn exp_f32<S: Simd>(s: S, x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // 1.5 * 2^23: adding and subtracting it rounds to the nearest integer.
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let n = (x * LOG2E + ROUND) - ROUND;
    let r = s.fma1(-n, LN2_LO, s.fma1(-n, LN2_HI, x));
    let r2 = r * r;
    let mut p = s.fma1(1.987_569_1e-4, r, 1.398_199_9e-3);
    p = s.fma1(p, r, 8.333_452e-3);
    p = s.fma1(p, r, 4.166_579_6e-2);
    p = s.fma1(p, r, 1.666_666_5e-1);
    p = s.fma1(p, r, 0.5);
    let p = s.fma1(p, r2, r) + 1.0;
    // 2^n without a float-to-int conversion (which would not vectorise): n + 127 + 2^23
    // holds the biased exponent n + 127 in its low mantissa bits; shift it into place.
    let scale = f32::from_bits((n + 8_388_735.0).to_bits() << 23);
    p * scale
}

/// Logistic sigmoid `1 / (1 + e^-x)`.
#[inline(always)]
fn sigmoid_f32<S: Simd>(s: S, x: f32) -> f32 {
    1.0 / (1.0 + exp_f32(s, -x))
}

/// `tanh x = 2 σ(2x) − 1`: absolute error ≈ 1e-7 (checked in the tests), the relative
/// accuracy near 0 being traded for one shared, branch-free code path.
#[inline(always)]
fn tanh_f32<S: Simd>(s: S, x: f32) -> f32 {
    2.0 * sigmoid_f32(s, 2.0 * x) - 1.0
}

/// [`exp_f32`] on 16 lanes: the same operations in the same order, so every lane has the bits
/// of the scalar function (NaN stays NaN: the clamp keeps `x` when a comparison fails).
#[inline(always)]
fn exp_v<S: Simd>(s: S, x: S::V) -> S::V {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    const ROUND: f32 = 12_582_912.0;
    let c = |v: f32| s.splat(v);
    let x = s.min(c(88.0), s.max(c(-87.0), x));
    let n = s.sub(s.add(s.mul(x, c(LOG2E)), c(ROUND)), c(ROUND));
    // -n (exact) times the split ln 2.
    let m = s.mul(n, c(-1.0));
    let r = s.mul_add(m, c(LN2_LO), s.mul_add(m, c(LN2_HI), x));
    let r2 = s.mul(r, r);
    let mut p = s.mul_add(c(1.987_569_1e-4), r, c(1.398_199_9e-3));
    p = s.mul_add(p, r, c(8.333_452e-3));
    p = s.mul_add(p, r, c(4.166_579_6e-2));
    p = s.mul_add(p, r, c(1.666_666_5e-1));
    p = s.mul_add(p, r, c(0.5));
    let p = s.add(s.mul_add(p, r2, r), c(1.0));
    let scale = s.shl23(s.add(n, c(8_388_735.0)));
    s.mul(p, scale)
}

/// [`sigmoid_f32`] on 16 lanes (same bits per lane).
#[inline(always)]
fn sigmoid_v<S: Simd>(s: S, x: S::V) -> S::V {
    let one = s.splat(1.0);
    s.div(one, s.add(one, exp_v(s, s.mul(x, s.splat(-1.0)))))
}

/// [`tanh_f32`] on 16 lanes (same bits per lane).
#[inline(always)]
fn tanh_v<S: Simd>(s: S, x: S::V) -> S::V {
    let two = s.splat(2.0);
    s.sub(s.mul(two, sigmoid_v(s, s.mul(two, x))), s.splat(1.0))
}

/// One-layer LSTM cell whose input is a 2-D displacement passed through a spatial embedding
/// `Linear(2, E)`, folded into the input weights at load time:
/// `W_ih (W_e d + b_e) + b_ih + b_hh = (W_ih W_e) d + (W_ih b_e + b_ih + b_hh)`.
///
/// It steps many rows (agents) at once; a row is `[d_x, d_y, h_0 .. h_{H-1}]` (see
/// [`Lstm::row_len`]), the gate product reading the displacement and the hidden state in one
/// pass.
///
/// With f32 sums ([`Accumulate::F32`]) a step is one fused kernel per register tile of rows:
/// the four gates of 16 hidden units stay in registers from the product through the
/// activations to the cell update ([`LstmCell::Fused`]); with f64 sums the gates are a
/// [`Dense`] layer followed by an element-wise pass ([`LstmCell::Dense`]). Both evaluate the
/// same operations in the same order per output and give the same bits.
#[derive(Debug, Clone)]
pub(crate) struct Lstm {
    h: usize,
    /// `gates = W [d ; h] + b`, `W` `[4H, 2 + H]`, gate order i, f, g, o.
    cell: LstmCell,
}

/// The packed gate product of an [`Lstm`].
#[derive(Debug, Clone)]
pub(crate) enum LstmCell {
    /// One dense layer `[4H, 2 + H]` (any [`Accumulate`]); activations in a second pass.
    Dense(Dense),
    /// f32 sums, gate-aligned: for hidden block `hb` (16 units, `ceil(H/16)` blocks), the
    /// blocks `4 hb + g` (gate `g` = i, f, g, o) of `w` (`[4 ceil(H/16)][2 + H]`, input-major,
    /// zero padded) and of `b` (`[4 ceil(H/16)]`). `dense` is the same product packed as
    /// [`LstmCell::Dense`], for the portable path: there a 16-lane vector takes four SSE
    /// registers, four gates of a row do not fit in the register file, and the two-pass form
    /// is faster (same bits either way).
    Fused {
        w: Vec<Block>,
        b: Vec<Block>,
        dense: Dense,
    },
}

/// Packs the gate matrix `w` (`[4H, in]`) and bias `b` (`[4H]`) gate-aligned (see
/// [`LstmCell::Fused`]).
fn pack_gates(w: &[f32], b: &[f32], h: usize, in_dim: usize) -> (Vec<Block>, Vec<Block>) {
    let nhb = h.div_ceil(LANES);
    let mut pw = vec![[0.0f32; LANES]; 4 * nhb * in_dim];
    let mut pb = vec![[0.0f32; LANES]; 4 * nhb];
    for g in 0..4 {
        for u in 0..h {
            let (blk, l, row) = (4 * (u / LANES) + g, u % LANES, g * h + u);
            pb[blk][l] = b[row];
            for k in 0..in_dim {
                pw[blk * in_dim + k][l] = w[row * in_dim + k];
            }
        }
    }
    (pw, pb)
}

impl Lstm {
    /// From the PyTorch tensors `[emb_w, emb_b, w_ih, w_hh, b_ih, b_hh]`: `emb_w [E, 2]`,
    /// `emb_b [E]`, `w_ih [4H, E]`, `w_hh [4H, H]`, `b_ih`, `b_hh` `[4H]`, with `h` = H. Folding
    /// is done in f64 and rounded once.
    pub(crate) fn new(t: [&[f32]; 6], h: usize, acc: Accumulate) -> Self {
        Self::with_cell(t, h, acc, acc == Accumulate::F32)
    }

    /// As [`Lstm::new`]; `fused` selects [`LstmCell::Fused`] (f32 sums only).
    fn with_cell(t: [&[f32]; 6], h: usize, acc: Accumulate, fused: bool) -> Self {
        debug_assert!(!fused || acc == Accumulate::F32);
        let [emb_w, emb_b, w_ih, w_hh, b_ih, b_hh] = t;
        let e = emb_b.len();
        let rows = 4 * h;
        let in_dim = 2 + h;
        let mut w = vec![0.0f32; rows * in_dim];
        let mut b = vec![0.0f32; rows];
        for r in 0..rows {
            let wr = &w_ih[r * e..(r + 1) * e];
            let mut d0 = 0.0f64;
            let mut d1 = 0.0f64;
            let mut bb = f64::from(b_ih[r]) + f64::from(b_hh[r]);
            for k in 0..e {
                d0 += f64::from(wr[k]) * f64::from(emb_w[2 * k]);
                d1 += f64::from(wr[k]) * f64::from(emb_w[2 * k + 1]);
                bb += f64::from(wr[k]) * f64::from(emb_b[k]);
            }
            w[r * in_dim] = d0 as f32;
            w[r * in_dim + 1] = d1 as f32;
            w[r * in_dim + 2..(r + 1) * in_dim].copy_from_slice(&w_hh[r * h..(r + 1) * h]);
            b[r] = bb as f32;
            if (2 * h..3 * h).contains(&r) {
                // g̃ = tanh(x) is evaluated as 2 σ(2x) − 1: pre-scale its rows (exact).
                for v in &mut w[r * in_dim..(r + 1) * in_dim] {
                    *v *= 2.0;
                }
                b[r] *= 2.0;
            }
        }
        let cell = if fused {
            let dense = Dense::new(&w, &b, rows, in_dim, acc);
            let (w, b) = pack_gates(&w, &b, h, in_dim);
            LstmCell::Fused { w, b, dense }
        } else {
            LstmCell::Dense(Dense::new(&w, &b, rows, in_dim, acc))
        };
        Self { h, cell }
    }

    /// Length of one row `[d ; h]`: `2 + H`.
    pub(crate) fn row_len(&self) -> usize {
        2 + self.h
    }

    /// Gate scratch of `m` rows: `m * 4H`.
    pub(crate) fn gates_len(&self, m: usize) -> usize {
        m * 4 * self.h
    }

    /// One step of `m` rows. Row `r` of `xh` starts at `r * ldx` (`ldx >= 2 + H`) with
    /// `[d ; h]` (displacement in metres); its `h` part is updated in place, the rest of the
    /// row is left as it is. `c` is the cell state `[m, H]`, updated in place; `g` is scratch
    /// of at least [`Lstm::gates_len`].
    pub(crate) fn step(
        &self,
        isa: Isa,
        xh: &mut [f32],
        ldx: usize,
        c: &mut [f32],
        g: &mut [f32],
        m: usize,
    ) {
        debug_assert!(ldx >= self.row_len());
        match &self.cell {
            LstmCell::Fused { w, b, .. } if isa.path() != SimdPath::Portable => {
                isa.run(LstmFused {
                    h: self.h,
                    w,
                    b,
                    xh,
                    ldx,
                    c,
                    hnew: g,
                    m,
                });
            }
            LstmCell::Dense(gates) | LstmCell::Fused { dense: gates, .. } => {
                isa.run(LstmRows {
                    h: self.h,
                    gates,
                    xh,
                    ldx,
                    c,
                    g,
                    m,
                });
            }
        }
    }
}

/// An [`LstmCell::Dense`] step: the gate layer, then the activations and the cell update.
struct LstmRows<'a> {
    h: usize,
    gates: &'a Dense,
    xh: &'a mut [f32],
    ldx: usize,
    c: &'a mut [f32],
    g: &'a mut [f32],
    m: usize,
}

impl Kernel for LstmRows<'_> {
    type Out = ();
    #[inline(always)]
    fn run<S: Simd>(self, s: S) {
        let Self {
            h: n,
            gates,
            xh,
            ldx,
            c,
            g,
            m,
        } = self;
        let rl = 2 + n;
        let g = &mut g[..m * 4 * n];
        dense_rows(s, gates, xh, ldx, m, g, 4 * n, false);
        // The g̃ rows were scaled by 2 at load time (exact), so one sigmoid pass serves all
        // four gates: tanh(x) = 2 σ(2x) − 1.
        for v in g.iter_mut() {
            *v = sigmoid_f32(s, *v);
        }
        for (r, gr) in g.chunks_exact(4 * n).enumerate() {
            let (gi, rest) = gr.split_at(n);
            let (gf, rest) = rest.split_at(n);
            let (gg, go) = rest.split_at(n);
            let h = &mut xh[r * ldx + 2..r * ldx + rl];
            let c = &mut c[r * n..(r + 1) * n];
            for k in 0..n {
                let gt = 2.0 * gg[k] - 1.0;
                let cn = s.fma1(gf[k], c[k], gi[k] * gt);
                c[k] = cn;
                h[k] = go[k] * tanh_f32(s, cn);
            }
        }
    }
}

/// An [`LstmCell::Fused`] step: per register tile of up to `S::LSTM_ROWS` rows and per block of
/// 16 hidden units, the four gate sums in registers (each from its bias, inputs in order, as
/// [`dense_rows`]), then the activations and the cell update on those registers with the
/// operations of [`LstmRows`] in the same order (same bits). New hidden states go to `hnew`
/// (`[m, H]` scratch) and are copied into the rows' `h` part once the tile has read them.
struct LstmFused<'a> {
    h: usize,
    w: &'a [Block],
    b: &'a [Block],
    xh: &'a mut [f32],
    ldx: usize,
    c: &'a mut [f32],
    hnew: &'a mut [f32],
    m: usize,
}

impl Kernel for LstmFused<'_> {
    type Out = ();
    #[inline(always)]
    fn run<S: Simd>(self, s: S) {
        let Self {
            h,
            w,
            b,
            xh,
            ldx,
            c,
            hnew,
            m,
        } = self;
        let rl = 2 + h;
        count_macs(m * rl * 4 * h);
        let mut r = 0;
        while r < m {
            let mb = (m - r).min(S::LSTM_ROWS);
            match mb {
                1 => lstm_tile::<S, 1>(s, h, w, b, xh, ldx, c, hnew, r),
                2 => lstm_tile::<S, 2>(s, h, w, b, xh, ldx, c, hnew, r),
                3 => lstm_tile::<S, 3>(s, h, w, b, xh, ldx, c, hnew, r),
                4 => lstm_tile::<S, 4>(s, h, w, b, xh, ldx, c, hnew, r),
                _ => unreachable!("fused LSTM tiles are at most 4 rows"),
            }
            for row in r..r + mb {
                xh[row * ldx + 2..row * ldx + rl].copy_from_slice(&hnew[row * h..(row + 1) * h]);
            }
            r += mb;
        }
    }
}

/// Loads lanes `lane0..lane0 + 16` of `x` (zero beyond its end).
#[inline(always)]
fn load_part<S: Simd>(s: S, x: &[f32], lane0: usize) -> S::V {
    let n = (x.len() - lane0).min(LANES);
    if let Ok(full) = <&Block>::try_from(&x[lane0..lane0 + n]) {
        s.load(full)
    } else {
        let mut t = [0.0f32; LANES];
        t[..n].copy_from_slice(&x[lane0..lane0 + n]);
        s.load(&t)
    }
}

/// Stores the first `min(16, y.len() - lane0)` lanes of `v` at `y[lane0..]`.
#[inline(always)]
fn store_part<S: Simd>(s: S, v: S::V, y: &mut [f32], lane0: usize) {
    let n = (y.len() - lane0).min(LANES);
    f32::store_f32(s, v, false, &mut y[lane0..lane0 + n]);
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn lstm_tile<S: Simd, const MB: usize>(
    s: S,
    h: usize,
    w: &[Block],
    b: &[Block],
    xh: &[f32],
    ldx: usize,
    c: &mut [f32],
    hnew: &mut [f32],
    r0: usize,
) {
    let rl = 2 + h;
    let (one, two) = (s.splat(1.0), s.splat(2.0));
    for hb in 0..h.div_ceil(LANES) {
        let mut init = [s.splat(0.0); 4];
        for (g, v) in init.iter_mut().enumerate() {
            *v = s.load(&b[4 * hb + g]);
        }
        let acc = tile::<S, f32, MB, 4>(s, w, rl, 4 * hb, xh, ldx, r0, init);
        for (r, [gi, gf, gg, go]) in acc.into_iter().enumerate() {
            let row = r0 + r;
            let (i, f, g, o) = (
                sigmoid_v(s, gi),
                sigmoid_v(s, gf),
                sigmoid_v(s, gg),
                sigmoid_v(s, go),
            );
            // g̃ = tanh = 2 σ(2x) − 1 (its rows were pre-scaled by 2 at load time).
            let gt = s.sub(s.mul(two, g), one);
            let cr = &mut c[row * h..(row + 1) * h];
            let cn = s.mul_add(f, load_part(s, cr, hb * LANES), s.mul(i, gt));
            store_part(s, cn, cr, hb * LANES);
            let hn = s.mul(o, tanh_v(s, cn));
            store_part(s, hn, &mut hnew[row * h..(row + 1) * h], hb * LANES);
        }
    }
}

/// One (query, neighbour) pair of the pooling: running-max row `q`, agent-term row `j`, and
/// the offset `d = p_j - p_i` (metres).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Pair {
    /// Row of the running maximum (the query agent's slot).
    pub(crate) q: u32,
    /// Row of the neighbour's agent term.
    pub(crate) j: u32,
    /// Offset from the query to the neighbour, metres.
    pub(crate) d: [f32; 2],
}

/// Social-GAN's `PoolHiddenNet` with the first layer split:
/// `u_ij = relu(W2 relu(W1 [W_e (p_j - p_i) + b_e ; h_j] + b1) + b2)`, `pool_i = max_j u_ij`.
///
/// `W1 [W_e d + b_e ; h_j] + b1 = t_j + (W1e W_e) d` with the per-agent term
/// `t_j = W1h h_j + (W1e b_e + b1)` computed once per agent ([`Pool::terms`]); per pair only
/// two multiply-adds per hidden unit remain, then the second layer (the `O(n²)` part), which
/// runs on register tiles of pairs ([`Pool::fold_grid`]). Its bias and ReLU are applied after the
/// max ([`Pool::finish`]; exact: rounding is monotonic).
#[derive(Debug, Clone)]
pub(crate) struct Pool {
    p: usize,
    b: usize,
    /// `W1e W_e`, x column `[P]` (zero padded to blocks).
    wpx: Vec<Block>,
    /// `W1e W_e`, y column `[P]` (zero padded to blocks).
    wpy: Vec<Block>,
    /// `t_j = W1h h_j + (W1e b_e + b1)`, in = hidden size of h, out = P.
    l1h: Dense,
    /// Second layer without bias, packed `[n_blocks][P]`.
    w2: Vec<Block>,
    /// `[B]`.
    b2: Vec<f32>,
}

impl Pool {
    /// From the PyTorch tensors: `emb_w [E,2]`, `emb_b [E]`, `w1 [P, E+H]`, `b1 [P]`,
    /// `w2 [B, P]`, `b2 [B]`; `h` is the size of the pooled hidden states.
    pub(crate) fn new(t: [&[f32]; 6], h: usize, acc: Accumulate) -> Self {
        let [emb_w, emb_b, w1, b1, w2, b2] = t;
        let e = emb_b.len();
        let p = b1.len();
        let b = b2.len();
        let in1 = e + h;
        let mut wpx = vec![0.0f32; p];
        let mut wpy = vec![0.0f32; p];
        let mut c = vec![0.0f32; p];
        let mut w1h = vec![0.0f32; p * h];
        for r in 0..p {
            let row = &w1[r * in1..(r + 1) * in1];
            let (mut sx, mut sy, mut sc) = (0.0f64, 0.0f64, f64::from(b1[r]));
            for k in 0..e {
                sx += f64::from(row[k]) * f64::from(emb_w[2 * k]);
                sy += f64::from(row[k]) * f64::from(emb_w[2 * k + 1]);
                sc += f64::from(row[k]) * f64::from(emb_b[k]);
            }
            wpx[r] = sx as f32;
            wpy[r] = sy as f32;
            c[r] = sc as f32;
            w1h[r * h..(r + 1) * h].copy_from_slice(&row[e..]);
        }
        Self {
            p,
            b,
            wpx: pad::<f32>(&wpx),
            wpy: pad::<f32>(&wpy),
            l1h: Dense::new(&w1h, &c, p, h, acc),
            w2: pack::<f32>(w2, b, p),
            b2: b2.to_vec(),
        }
    }

    /// Row stride of agent terms: P rounded up to whole blocks.
    pub(crate) fn term_stride(&self) -> usize {
        self.p.div_ceil(LANES) * LANES
    }

    /// Output width B.
    pub(crate) fn out_dim(&self) -> usize {
        self.b
    }

    /// Length of a running-max row (B rounded up to whole blocks).
    pub(crate) fn acc_len(&self) -> usize {
        self.b.div_ceil(LANES) * LANES
    }

    /// Scratch length [`Pool::fold_grid`] needs for its first-layer rows.
    pub(crate) fn val_len(&self) -> usize {
        MAX_TILE_ROWS * self.term_stride()
    }

    /// Agent terms `t_j` of `m` agents: hidden states `h[r*ldh..]` (`[m, H]`) to
    /// `terms[r*term_stride..][..P]`. The padding lanes of a term row are never written.
    pub(crate) fn terms(&self, isa: Isa, h: &[f32], ldh: usize, m: usize, terms: &mut [f32]) {
        self.l1h
            .rows(isa, h, ldh, m, terms, self.term_stride(), false);
    }

    /// Starts running maxima: rows `rows` of `acc` (stride [`Pool::acc_len`]) to `-inf`.
    pub(crate) fn reset(&self, acc: &mut [f32], rows: std::ops::Range<usize>) {
        let al = self.acc_len();
        acc[rows.start * al..rows.end * al].fill(f32::NEG_INFINITY);
    }

    /// Folds every pair into its query's running maximum (the list form of
    /// [`Pool::fold_grid`], kept as its reference in the tests):
    /// `acc[q] = max(acc[q], W2 relu(t_j + (W1e W_e) d))` (second-layer bias and ReLU come in
    /// [`Pool::finish`]). `terms` rows have stride [`Pool::term_stride`], `acc` rows
    /// [`Pool::acc_len`]; `val` is scratch of [`Pool::val_len`]. The padding lanes of the
    /// referenced term rows must be finite (they are multiplied by zero weights).
    #[cfg(test)]
    pub(crate) fn fold(
        &self,
        isa: Isa,
        pairs: &[Pair],
        terms: &[f32],
        acc: &mut [f32],
        val: &mut [f32],
    ) {
        isa.run(PoolPairs {
            pool: self,
            pairs,
            terms,
            acc,
            val,
        });
    }

    /// Folds every pair of `grid` (generated inside the kernel, in its order, in register
    /// tiles of consecutive pairs) into its query's running maximum:
    /// `acc[q] = max(acc[q], W2 relu(t_j + (W1e W_e) d))` (second-layer bias and ReLU come in
    /// [`Pool::finish`]). `terms` rows have stride [`Pool::term_stride`], `acc` rows
    /// [`Pool::acc_len`]; `val` is scratch of [`Pool::val_len`]. The padding lanes of the
    /// referenced term rows must be finite (they are multiplied by zero weights). The same
    /// pairs given as a list in the same order give the same bits (tested).
    pub(crate) fn fold_grid(
        &self,
        isa: Isa,
        grid: PairGrid<'_>,
        terms: &[f32],
        acc: &mut [f32],
        val: &mut [f32],
    ) {
        isa.run(PoolGrid {
            pool: self,
            grid,
            terms,
            acc,
            val,
        });
    }

    /// `out[..B] = relu(acc + b2)`: the pooled vector of one agent from its running max.
    #[inline]
    pub(crate) fn finish(&self, acc: &[f32], out: &mut [f32]) {
        let b = self.b;
        for ((o, a), c) in out[..b].iter_mut().zip(&acc[..b]).zip(&self.b2[..b]) {
            *o = relu_nan(a + c);
        }
    }
}

#[cfg(test)]
struct PoolPairs<'a> {
    pool: &'a Pool,
    pairs: &'a [Pair],
    terms: &'a [f32],
    acc: &'a mut [f32],
    val: &'a mut [f32],
}

#[cfg(test)]
impl Kernel for PoolPairs<'_> {
    type Out = ();
    #[inline(always)]
    fn run<S: Simd>(self, s: S) {
        let Self {
            pool,
            pairs,
            terms,
            acc,
            val,
        } = self;
        count_macs(pairs.len() * (2 * pool.p + pool.p * pool.b));
        for chunk in pairs.chunks(S::TILE_ROWS) {
            fold_chunk(s, pool, chunk, terms, acc, val);
        }
    }
}

/// The pairs `(i, j)`, `i` in `queries` (outer), `j` in `js` (inner), of agents at `pos`
/// (`[n, 2]`, metres): the pair list [`Pool::fold_grid`] generates inside its kernel, in the
/// order a list built by the same loops would have.
#[derive(Debug, Clone)]
pub(crate) struct PairGrid<'a> {
    /// Positions `[n, 2]`, metres.
    pub(crate) pos: &'a [f64],
    /// Query agents (running-max rows).
    pub(crate) queries: std::ops::Range<usize>,
    /// Neighbour agents (agent-term rows).
    pub(crate) js: std::ops::Range<usize>,
}

struct PoolGrid<'a> {
    pool: &'a Pool,
    grid: PairGrid<'a>,
    terms: &'a [f32],
    acc: &'a mut [f32],
    val: &'a mut [f32],
}

impl Kernel for PoolGrid<'_> {
    type Out = ();
    #[inline(always)]
    fn run<S: Simd>(self, s: S) {
        let Self {
            pool,
            grid,
            terms,
            acc,
            val,
        } = self;
        let PairGrid { pos, queries, js } = grid;
        count_macs(queries.len() * js.len() * (2 * pool.p + pool.p * pool.b));
        // Chunks of `S::TILE_ROWS` consecutive pairs, exactly as `pairs.chunks` cuts a list.
        let mut chunk = [Pair::default(); MAX_TILE_ROWS];
        let mut len = 0;
        for i in queries {
            let (xi, yi) = (pos[2 * i], pos[2 * i + 1]);
            for j in js.clone() {
                chunk[len] = Pair {
                    q: i as u32,
                    j: j as u32,
                    d: [(pos[2 * j] - xi) as f32, (pos[2 * j + 1] - yi) as f32],
                };
                len += 1;
                if len == S::TILE_ROWS {
                    fold_chunk(s, pool, &chunk[..len], terms, acc, val);
                    len = 0;
                }
            }
        }
        if len > 0 {
            fold_chunk(s, pool, &chunk[..len], terms, acc, val);
        }
    }
}

/// Folds one register tile of pairs (at most `S::TILE_ROWS`) into the running maxima.
#[inline(always)]
fn fold_chunk<S: Simd>(
    s: S,
    pool: &Pool,
    chunk: &[Pair],
    terms: &[f32],
    acc: &mut [f32],
    val: &mut [f32],
) {
    let (p, ts) = (pool.p, pool.term_stride());
    let nblk = pool.w2.len() / p;
    let zero = s.splat(0.0);
    // First layer, row by row: relu(t_j + wpx dx + wpy dy).
    for (pr, v) in chunk.iter().zip(val.chunks_exact_mut(ts)) {
        let t = blocks(&terms[pr.j as usize * ts..(pr.j as usize + 1) * ts]);
        let (dx, dy) = (s.splat(pr.d[0]), s.splat(pr.d[1]));
        for (((vb, tb), wx), wy) in blocks_mut(v)
            .iter_mut()
            .zip(t)
            .zip(&pool.wpx)
            .zip(&pool.wpy)
        {
            let u = s.mul_add(dy, s.load(wy), s.mul_add(dx, s.load(wx), s.load(tb)));
            s.store(s.max(u, zero), vb);
        }
    }
    // Second layer on the whole tile, then the max into each pair's query row.
    let mb = chunk.len();
    let mut blk = 0;
    while blk < nblk {
        let ob = (nblk - blk).min(S::TILE_BLOCKS);
        by_tile!(mb, ob, pool_tile::<S>(s, pool, chunk, val, blk, acc));
        blk += ob;
    }
}

#[inline(always)]
fn pool_tile<S: Simd, const MB: usize, const OB: usize>(
    s: S,
    pool: &Pool,
    chunk: &[Pair],
    val: &[f32],
    blk0: usize,
    acc: &mut [f32],
) {
    let (p, al) = (pool.p, pool.acc_len());
    let zero = s.splat(0.0);
    let sums = tile::<S, f32, MB, OB>(s, &pool.w2, p, blk0, val, pool.term_stride(), 0, [zero; OB]);
    // Consecutive pairs of the same query are reduced in registers first, so that each
    // running-max row is read and written once per run instead of once per pair.
    let mut r = 0;
    while r < MB {
        let q = chunk[r].q;
        let mut best = sums[r];
        r += 1;
        while r < MB && chunk[r].q == q {
            for o in 0..OB {
                best[o] = s.max(best[o], sums[r][o]);
            }
            r += 1;
        }
        let a = blocks_mut(&mut acc[q as usize * al..(q as usize + 1) * al]);
        for (o, v) in best.into_iter().enumerate() {
            let m = &mut a[blk0 + o];
            let new = s.max(s.load(m), v);
            s.store(new, m);
        }
    }
}

/// Two-layer mlp `relu(W2 relu(W1 x + b1) + b2)`.
#[derive(Debug, Clone)]
pub(crate) struct Mlp2 {
    l1: Dense,
    l2: Dense,
}

impl Mlp2 {
    /// From the PyTorch tensors `[w1, b1, w2, b2]`: `w1 [M, in]`, `b1 [M]`, `w2 [out, M]`,
    /// `b2 [out]`, with `in_dim` = in.
    pub(crate) fn new(t: [&[f32]; 4], in_dim: usize, acc: Accumulate) -> Self {
        let [w1, b1, w2, b2] = t;
        let m = b1.len();
        let out = b2.len();
        Self {
            l1: Dense::new(w1, b1, m, in_dim, acc),
            l2: Dense::new(w2, b2, out, m, acc),
        }
    }

    /// Hidden-layer scratch of `m` rows.
    pub(crate) fn hidden_len(&self, m: usize) -> usize {
        m * self.l1.out_dim()
    }

    /// Output size.
    pub(crate) fn out_dim(&self) -> usize {
        self.l2.out_dim()
    }

    /// `y[r*ldy..][..out] = mlp(x[r*ldx..])` for `m` rows; `hid` is scratch of
    /// [`Mlp2::hidden_len`].
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn rows(
        &self,
        isa: Isa,
        x: &[f32],
        ldx: usize,
        m: usize,
        hid: &mut [f32],
        y: &mut [f32],
        ldy: usize,
    ) {
        isa.run(MlpRows {
            mlp: self,
            x,
            ldx,
            m,
            hid,
            y,
            ldy,
        });
    }

    /// In place: row `r` of `xy` (`xy[r*ld..]`, `m` rows) is the input; its first `out`
    /// lanes receive the mlp's output once every input of the layer has been read (the
    /// first layer runs on all rows before the second writes). `hid` is scratch of
    /// [`Mlp2::hidden_len`].
    pub(crate) fn rows_in_place(
        &self,
        isa: Isa,
        xy: &mut [f32],
        ld: usize,
        m: usize,
        hid: &mut [f32],
    ) {
        isa.run(MlpInPlace {
            mlp: self,
            xy,
            ld,
            m,
            hid,
        });
    }
}

/// [`Mlp2::rows_in_place`] as a kernel.
struct MlpInPlace<'a> {
    mlp: &'a Mlp2,
    xy: &'a mut [f32],
    ld: usize,
    m: usize,
    hid: &'a mut [f32],
}

impl Kernel for MlpInPlace<'_> {
    type Out = ();
    #[inline(always)]
    fn run<S: Simd>(self, s: S) {
        let Self {
            mlp,
            xy,
            ld,
            m,
            hid,
        } = self;
        let hd = mlp.l1.out_dim();
        dense_rows(s, &mlp.l1, xy, ld, m, hid, hd, true);
        dense_rows(s, &mlp.l2, hid, hd, m, xy, ld, true);
    }
}

struct MlpRows<'a> {
    mlp: &'a Mlp2,
    x: &'a [f32],
    ldx: usize,
    m: usize,
    hid: &'a mut [f32],
    y: &'a mut [f32],
    ldy: usize,
}

impl Kernel for MlpRows<'_> {
    type Out = ();
    #[inline(always)]
    fn run<S: Simd>(self, s: S) {
        let Self {
            mlp,
            x,
            ldx,
            m,
            hid,
            y,
            ldy,
        } = self;
        let hd = mlp.l1.out_dim();
        dense_rows(s, &mlp.l1, x, ldx, m, hid, hd, true);
        dense_rows(s, &mlp.l2, hid, hd, m, y, ldy, true);
    }
}

/// `iterations` rounds of `A` independent 16-lane multiply-adds: the instruction set's
/// multiply-add throughput with no memory traffic. Returns the multiply-adds done and a
/// checksum (so the loop cannot be optimised away).
pub(crate) struct PeakLoop {
    pub(crate) iterations: u64,
    /// Multiplier close to 1 (kept opaque to the optimiser by the caller).
    pub(crate) a: f32,
}

impl Kernel for PeakLoop {
    type Out = (u64, f32);
    #[inline(always)]
    fn run<S: Simd>(self, s: S) -> (u64, f32) {
        // Enough independent chains to cover the multiply-add latency of each unit.
        match S::PATH {
            SimdPath::Avx512 => peak::<S, 12>(s, self.iterations, self.a),
            SimdPath::Avx2 => peak::<S, 6>(s, self.iterations, self.a),
            SimdPath::Portable => peak::<S, 3>(s, self.iterations, self.a),
        }
    }
}

#[inline(always)]
fn peak<S: Simd, const A: usize>(s: S, iterations: u64, a: f32) -> (u64, f32) {
    let (av, bv) = (s.splat(a), s.splat(1e-3));
    let mut acc = [s.splat(0.0); A];
    for (i, v) in acc.iter_mut().enumerate() {
        *v = s.splat(i as f32 * 1e-2);
    }
    for _ in 0..iterations {
        for v in &mut acc {
            *v = s.mul_add(*v, av, bv);
        }
    }
    let mut sum = 0.0f32;
    for v in acc {
        let mut t = [0.0f32; LANES];
        s.store(v, &mut t);
        sum += t.iter().sum::<f32>();
    }
    (iterations * (A * LANES) as u64, sum)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::simd::supported_simd_paths;

    /// Evaluates the activations on one instruction set (test helper).
    struct Activations<'a> {
        xs: &'a [f32],
        sig: &'a mut Vec<f32>,
        tanh: &'a mut Vec<f32>,
        exp: &'a mut Vec<f32>,
    }
    impl Kernel for Activations<'_> {
        type Out = ();
        #[inline(always)]
        fn run<S: Simd>(self, s: S) {
            self.sig.extend(self.xs.iter().map(|&x| sigmoid_f32(s, x)));
            self.tanh.extend(self.xs.iter().map(|&x| tanh_f32(s, x)));
            self.exp.extend(self.xs.iter().map(|&x| exp_f32(s, x)));
        }
    }

    fn isas() -> Vec<Isa> {
        supported_simd_paths()
            .into_iter()
            .map(|p| Isa::new(p).unwrap())
            .collect()
    }

    #[test]
    fn activations_are_accurate_on_every_path() {
        let mut xs: Vec<f32> = (-400_000..=400_000).map(|i| i as f32 * 5e-5).collect();
        xs.extend([-100.0, -60.0, -30.0, 30.0, 60.0, 100.0, 1e-30, -1e-30, 0.0]);
        let mut fused: Option<Vec<f32>> = None;
        for isa in isas() {
            let (mut sig, mut tanh, mut exp) = (Vec::new(), Vec::new(), Vec::new());
            isa.run(Activations {
                xs: &xs,
                sig: &mut sig,
                tanh: &mut tanh,
                exp: &mut exp,
            });
            let (mut worst_sig, mut worst_tanh, mut worst_exp) = (0.0f64, 0.0f64, 0.0f64);
            for (((&x, &sv), &tv), &ev) in xs.iter().zip(&sig).zip(&tanh).zip(&exp) {
                let x = f64::from(x);
                worst_sig = worst_sig.max((f64::from(sv) - 1.0 / (1.0 + (-x).exp())).abs());
                worst_tanh = worst_tanh.max((f64::from(tv) - x.tanh()).abs());
                if (-86.9..=87.9).contains(&x) {
                    let e = x.exp();
                    worst_exp = worst_exp.max(((f64::from(ev) - e) / e).abs());
                }
            }
            let p = isa.path();
            assert!(worst_sig < 1.5e-7, "{p}: sigmoid abs error {worst_sig:e}");
            assert!(worst_tanh < 2.5e-7, "{p}: tanh abs error {worst_tanh:e}");
            assert!(worst_exp < 3e-7, "{p}: exp rel error {worst_exp:e}");
            // The fused paths compute the same operations: same bits.
            if p.is_fused() {
                let all: Vec<f32> = sig.into_iter().chain(tanh).chain(exp).collect();
                match &fused {
                    None => fused = Some(all),
                    Some(f) => assert!(
                        f.iter().zip(&all).all(|(a, b)| a.to_bits() == b.to_bits()),
                        "{p}: activations differ from the other fused path"
                    ),
                }
            }
        }
    }

    /// Deterministic values in [-1, 1).
    fn values(seed: u32, n: usize) -> Vec<f32> {
        let mut x = seed.wrapping_mul(2_654_435_761).max(1);
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                (f64::from(x) / f64::from(u32::MAX) * 2.0 - 1.0) as f32
            })
            .collect()
    }

    fn dot(w: &[f32], x: &[f32]) -> f64 {
        w.iter()
            .zip(x)
            .map(|(a, b)| f64::from(*a) * f64::from(*b))
            .sum()
    }

    /// Dense rows against a straightforward scalar reference, bit for bit, on every path and in
    /// both precisions: each output starts from its bias and adds its terms in input order, one
    /// multiply-add each, rounded as the path rounds (fused, or product then sum); f64 sums take
    /// the f32 weights and inputs widened and are rounded to f32 once; ReLU last, NaN kept.
    /// Random shapes (seeded), with row counts, output widths and input lengths that are and
    /// are not multiples of the register tile's rows, the blocks' lanes (16 f32, 8 f64) and
    /// the tile's blocks, and row strides with padding that must stay unwritten.
    #[test]
    fn dense_rows_equal_scalar_reference_bits() {
        fn reference<T: Copy>(
            fma: impl Fn(T, T, T) -> T,
            widen: impl Fn(f32) -> T,
            round: impl Fn(T) -> f32,
            (w, b, x): (&[f32], &[f32], &[f32]),
            relu: bool,
        ) -> Vec<f32> {
            let inp = x.len();
            b.iter()
                .enumerate()
                .map(|(o, &bo)| {
                    let mut acc = widen(bo);
                    for (k, &xk) in x.iter().enumerate() {
                        acc = fma(widen(xk), widen(w[o * inp + k]), acc);
                    }
                    let v = round(acc);
                    if relu { max_nan(v, 0.0) } else { v }
                })
                .collect()
        }
        let mut seed = 0x2545_f491_u32;
        let mut next = |n: usize| {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed as usize % n
        };
        // Fixed remainder cases first, then random shapes.
        let mut shapes = vec![(1, 1, 1), (17, 9, 3), (8, 16, 5), (33, 1, 9), (47, 31, 13)];
        for _ in 0..40 {
            shapes.push((1 + next(70), 1 + next(40), 1 + next(19)));
        }
        for (case, &(out, inp, m)) in shapes.iter().enumerate() {
            let w = values(100 + case as u32, out * inp);
            let b = values(200 + case as u32, out);
            let (ldx, ldy) = (inp + next(3), out + 1 + next(3));
            let x = values(300 + case as u32, m * ldx);
            for acc in [Accumulate::F32, Accumulate::F64] {
                let d = Dense::new(&w, &b, out, inp, acc);
                for isa in isas() {
                    let fused = isa.path().is_fused();
                    for relu in [false, true] {
                        let mut y = vec![f32::NAN; m * ldy];
                        d.rows(isa, &x, ldx, m, &mut y, ldy, relu);
                        for r in 0..m {
                            let args = (&w[..], &b[..], &x[r * ldx..r * ldx + inp]);
                            let want = match acc {
                                Accumulate::F32 => reference(
                                    |a: f32, b, c| if fused { a.mul_add(b, c) } else { a * b + c },
                                    |v| v,
                                    |v| v,
                                    args,
                                    relu,
                                ),
                                Accumulate::F64 => reference(
                                    |a: f64, b, c| if fused { a.mul_add(b, c) } else { a * b + c },
                                    f64::from,
                                    |v| v as f32,
                                    args,
                                    relu,
                                ),
                            };
                            let got = &y[r * ldy..(r + 1) * ldy];
                            let bits =
                                |v: &[f32]| v.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                            assert_eq!(
                                bits(&got[..out]),
                                bits(&want),
                                "{} {acc:?} {out}x{inp}, {m} rows, row {r}, relu {relu}",
                                isa.path()
                            );
                            assert!(got[out..].iter().all(|v| v.is_nan()), "wrote past the row");
                        }
                    }
                }
            }
        }
    }

    /// Dense rows on every path and every row count / output width that exercises partial
    /// tiles and blocks: close to the f64 product, identical to row-by-row evaluation, and
    /// identical between the fused paths.
    #[test]
    fn dense_rows_match_f64_and_are_tiling_invariant() {
        for (out, inp) in [(2, 9), (13, 7), (16, 16), (24, 64), (33, 5), (128, 34)] {
            let w = values(11, out * inp);
            let b = values(12, out);
            for acc in [Accumulate::F32, Accumulate::F64] {
                let d = Dense::new(&w, &b, out, inp, acc);
                let m = 11;
                let ldx = inp + 3;
                let x = values(13, m * ldx);
                let mut fused: Option<Vec<u32>> = None;
                for isa in isas() {
                    for relu in [false, true] {
                        let ldy = out + 1;
                        let mut y = vec![f32::NAN; m * ldy];
                        d.rows(isa, &x, ldx, m, &mut y, ldy, relu);
                        for r in 0..m {
                            // One row at a time gives the same bits.
                            let mut y1 = vec![f32::NAN; out];
                            d.rows(isa, &x[r * ldx..], ldx, 1, &mut y1, out, relu);
                            assert_eq!(y1[..], y[r * ldy..r * ldy + out]);
                            assert!(y[r * ldy + out].is_nan(), "wrote past the row");
                            for o in 0..out {
                                let mut e =
                                    dot(&w[o * inp..(o + 1) * inp], &x[r * ldx..r * ldx + inp])
                                        + f64::from(b[o]);
                                if relu {
                                    e = e.max(0.0);
                                }
                                let got = f64::from(y[r * ldy + o]);
                                assert!((got - e).abs() < 1e-5, "{} {out}x{inp}", isa.path());
                            }
                        }
                        if isa.path().is_fused() && relu {
                            let bits: Vec<u32> = y.iter().map(|v| v.to_bits()).collect();
                            match &fused {
                                None => fused = Some(bits),
                                Some(f) => assert_eq!(f, &bits, "fused paths differ"),
                            }
                        }
                    }
                }
            }
        }
    }

    /// The fused f32 LSTM step gives the bits of the two-pass one (gate layer, then the
    /// element-wise activations and cell update) on every path, for hidden sizes with full and
    /// partial 16-lane blocks and row counts with full and partial register tiles, over
    /// several steps; and it is close to an f64 evaluation of the LSTM equations.
    #[test]
    fn fused_lstm_step_matches_two_pass_bits() {
        for h in [16, 9, 20, 32] {
            let e = 5;
            let emb_w = values(21, e * 2);
            let emb_b = values(22, e);
            let w_ih: Vec<f32> = values(23, 4 * h * e).iter().map(|v| v * 0.5).collect();
            let w_hh: Vec<f32> = values(24, 4 * h * h).iter().map(|v| v * 0.5).collect();
            let b_ih = values(25, 4 * h);
            let b_hh = values(26, 4 * h);
            let t = [&emb_w, &emb_b, &w_ih, &w_hh, &b_ih, &b_hh].map(Vec::as_slice);
            let make = |fused| Lstm::with_cell(t, h, Accumulate::F32, fused);
            let (fused, two_pass) = (make(true), make(false));
            assert!(matches!(fused.cell, LstmCell::Fused { .. }));
            assert!(matches!(two_pass.cell, LstmCell::Dense(_)));
            let rl = fused.row_len();
            // Rows with 3 lanes of padding that the step must leave alone.
            let ld = rl + 3;
            for isa in isas() {
                for m in [1, 3, 4, 5, 8, 11] {
                    let mut xh = values(27 + m as u32, m * ld);
                    let pad: Vec<f32> = (0..m)
                        .flat_map(|r| xh[r * ld + rl..(r + 1) * ld].to_vec())
                        .collect();
                    let mut c = values(40 + m as u32, m * h);
                    let (mut xh2, mut c2) = (xh.clone(), c.clone());
                    let mut g = vec![0.0f32; fused.gates_len(m)];
                    for step in 0..3 {
                        // f64 reference of this step from the current state.
                        let mut want_h = vec![0.0f64; m * h];
                        let mut want_c = vec![0.0f64; m * h];
                        for r in 0..m {
                            let x = &xh[r * ld..r * ld + rl];
                            let emb: Vec<f64> = (0..e)
                                .map(|k| {
                                    f64::from(emb_w[2 * k]) * f64::from(x[0])
                                        + f64::from(emb_w[2 * k + 1]) * f64::from(x[1])
                                        + f64::from(emb_b[k])
                                })
                                .collect();
                            let gate = |row: usize| {
                                let mut v = f64::from(b_ih[row]) + f64::from(b_hh[row]);
                                for k in 0..e {
                                    v += f64::from(w_ih[row * e + k]) * emb[k];
                                }
                                v + dot(&w_hh[row * h..(row + 1) * h], &x[2..])
                            };
                            let sig = |v: f64| 1.0 / (1.0 + (-v).exp());
                            for u in 0..h {
                                let (i, f) = (sig(gate(u)), sig(gate(h + u)));
                                let (gg, o) = (gate(2 * h + u).tanh(), sig(gate(3 * h + u)));
                                let cn = f * f64::from(c[r * h + u]) + i * gg;
                                want_c[r * h + u] = cn;
                                want_h[r * h + u] = o * cn.tanh();
                            }
                        }
                        fused.step(isa, &mut xh, ld, &mut c, &mut g, m);
                        two_pass.step(isa, &mut xh2, ld, &mut c2, &mut g, m);
                        let pad_now: Vec<f32> = (0..m)
                            .flat_map(|r| xh[r * ld + rl..(r + 1) * ld].to_vec())
                            .collect();
                        assert_eq!(pad, pad_now, "the step wrote past the rows' [d ; h]");
                        let p = isa.path();
                        assert_eq!(xh, xh2, "{p}: h {h}, {m} rows, step {step}: h bits differ");
                        assert_eq!(c, c2, "{p}: h {h}, {m} rows, step {step}: c bits differ");
                        for r in 0..m {
                            for u in 0..h {
                                let got = f64::from(xh[r * ld + 2 + u]);
                                assert!((got - want_h[r * h + u]).abs() < 1e-5, "{p}: h {got}");
                                let got = f64::from(c[r * h + u]);
                                assert!((got - want_c[r * h + u]).abs() < 1e-5, "{p}: c {got}");
                            }
                        }
                        // Next step: a new displacement, same states.
                        for r in 0..m {
                            xh[r * ld] = 0.3 * (step + r) as f32;
                            xh[r * ld + 1] = -0.2;
                            xh2[r * ld] = xh[r * ld];
                            xh2[r * ld + 1] = -0.2;
                        }
                    }
                }
            }
        }
    }

    /// Vector activations give the bits of the scalar ones on every path.
    #[test]
    fn vector_activations_match_scalar_bits() {
        struct Both<'a> {
            xs: &'a [f32],
        }
        impl Kernel for Both<'_> {
            type Out = Vec<(f32, [u32; 3], [u32; 3])>;
            #[inline(always)]
            fn run<S: Simd>(self, s: S) -> Self::Out {
                let mut out = Vec::new();
                for chunk in self.xs.chunks_exact(LANES) {
                    let v = s.load(chunk.try_into().unwrap());
                    let mut e = [0.0f32; LANES];
                    let mut g = [0.0f32; LANES];
                    let mut t = [0.0f32; LANES];
                    s.store(exp_v(s, v), &mut e);
                    s.store(sigmoid_v(s, v), &mut g);
                    s.store(tanh_v(s, v), &mut t);
                    for l in 0..LANES {
                        let x = chunk[l];
                        let scalar = [exp_f32(s, x), sigmoid_f32(s, x), tanh_f32(s, x)];
                        out.push((
                            x,
                            scalar.map(f32::to_bits),
                            [e[l], g[l], t[l]].map(f32::to_bits),
                        ));
                    }
                }
                out
            }
        }
        let mut xs: Vec<f32> = (-200_000..200_000).map(|i| i as f32 * 1.3e-4).collect();
        xs.extend([-100.0, -87.5, 88.5, 100.0, 1e-30, -1e-30, 0.0, -0.0]);
        xs.extend([
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            1e-40,
            -1e-40,
            3.0,
            -3.0,
            0.5,
        ]);
        xs.truncate(xs.len() / LANES * LANES);
        for isa in isas() {
            for (x, scalar, vector) in isa.run(Both { xs: &xs }) {
                if x.is_nan() {
                    assert!(
                        vector.iter().all(|b| f32::from_bits(*b).is_nan()),
                        "NaN kept"
                    );
                } else {
                    assert_eq!(scalar, vector, "{}: x = {x:e}", isa.path());
                }
            }
        }
    }

    /// The split pooling equals the literal one (embed, concatenate, two layers, max) to
    /// rounding on every path, whatever the order and grouping of the pairs.
    #[test]
    fn split_pool_matches_literal_pool() {
        let (e, h, p, b, n) = (16, 24, 40, 20, 6);
        let emb_w = values(1, e * 2);
        let emb_b = values(2, e);
        let w1: Vec<f32> = values(3, p * (e + h)).iter().map(|v| v * 0.3).collect();
        let b1 = values(4, p);
        let w2: Vec<f32> = values(5, b * p).iter().map(|v| v * 0.3).collect();
        let b2 = values(6, b);
        let hs = values(7, n * h);
        let pos: Vec<f32> = values(8, n * 2).iter().map(|v| v * 30.0).collect();
        for acc in [Accumulate::F32, Accumulate::F64] {
            let pool = Pool::new(
                [&emb_w, &emb_b, &w1, &b1, &w2, &b2].map(Vec::as_slice),
                h,
                acc,
            );
            let (ts, al) = (pool.term_stride(), pool.acc_len());
            let mut val = vec![0.0f32; pool.val_len()];
            let pairs: Vec<Pair> = (0..n)
                .flat_map(|i| (0..n).map(move |j| (i, j)))
                .map(|(i, j)| Pair {
                    q: i as u32,
                    j: j as u32,
                    d: [pos[2 * j] - pos[2 * i], pos[2 * j + 1] - pos[2 * i + 1]],
                })
                .collect();
            for isa in isas() {
                let mut terms = vec![0.0f32; n * ts];
                pool.terms(isa, &hs, h, n, &mut terms);
                let mut out = vec![0.0f32; n * b];
                let mut acc = vec![0.0f32; n * al];
                pool.reset(&mut acc, 0..n);
                pool.fold(isa, &pairs, &terms, &mut acc, &mut val);
                for i in 0..n {
                    pool.finish(&acc[i * al..], &mut out[i * b..(i + 1) * b]);
                }
                // Reversed pair order, one pair per call: same bits.
                let mut acc2 = vec![0.0f32; n * al];
                pool.reset(&mut acc2, 0..n);
                for pr in pairs.iter().rev() {
                    pool.fold(isa, std::slice::from_ref(pr), &terms, &mut acc2, &mut val);
                }
                assert_eq!(
                    acc,
                    acc2,
                    "{}: pair order or grouping changed bits",
                    isa.path()
                );
                // Pairs generated inside the kernel from f64 positions: same bits.
                let pos64: Vec<f64> = pos.iter().map(|&v| f64::from(v)).collect();
                let mut acc3 = vec![0.0f32; n * al];
                pool.reset(&mut acc3, 0..n);
                let grid = PairGrid {
                    pos: &pos64,
                    queries: 0..n,
                    js: 0..n,
                };
                pool.fold_grid(isa, grid, &terms, &mut acc3, &mut val);
                assert_eq!(acc, acc3, "{}: generated pairs changed bits", isa.path());
                // Literal evaluation in f64.
                for i in 0..n {
                    let mut best = vec![f64::NEG_INFINITY; b];
                    for j in 0..n {
                        let d = [pos[2 * j] - pos[2 * i], pos[2 * j + 1] - pos[2 * i + 1]];
                        let mut x: Vec<f32> = (0..e)
                            .map(|k| {
                                (dot(&emb_w[2 * k..2 * k + 2], &d) + f64::from(emb_b[k])) as f32
                            })
                            .collect();
                        x.extend_from_slice(&hs[j * h..(j + 1) * h]);
                        let h1: Vec<f32> = (0..p)
                            .map(|r| {
                                (dot(&w1[r * (e + h)..(r + 1) * (e + h)], &x) + f64::from(b1[r]))
                                    .max(0.0) as f32
                            })
                            .collect();
                        for (o, m) in best.iter_mut().enumerate() {
                            let u = (dot(&w2[o * p..(o + 1) * p], &h1) + f64::from(b2[o])).max(0.0);
                            *m = m.max(u);
                        }
                    }
                    for (o, m) in best.iter().enumerate() {
                        let got = f64::from(out[i * b + o]);
                        assert!(
                            (got - m).abs() < 1e-4 * (1.0 + m.abs()),
                            "{}: {got} vs {m}",
                            isa.path()
                        );
                    }
                }
            }
        }
    }

    /// IEEE-754 `maximum`/`minimum` in f64, the scalar truth for NaN propagation: NaN when
    /// either operand is NaN, else the larger (smaller) value.
    fn ieee_max(a: f64, b: f64) -> f64 {
        if a.is_nan() || b.is_nan() {
            f64::NAN
        } else {
            a.max(b)
        }
    }
    fn ieee_min(a: f64, b: f64) -> f64 {
        if a.is_nan() || b.is_nan() {
            f64::NAN
        } else {
            a.min(b)
        }
    }
    fn ieee_relu(x: f64) -> f64 {
        ieee_max(x, 0.0)
    }

    /// `got` agrees with the f64 truth `want`: NaN exactly where `want` is NaN, the same
    /// infinity where it is infinite, else within `tol`.
    fn agrees(got: f32, want: f64, tol: f64) -> bool {
        if want.is_nan() {
            got.is_nan()
        } else if want.is_infinite() {
            f64::from(got) == want
        } else {
            (f64::from(got) - want).abs() <= tol * (1.0 + want.abs())
        }
    }

    /// Non-finite values propagate through every kernel on every path as in the scalar f64
    /// truth (PyTorch's rule: `relu(NaN)`, `max(NaN, x)` and `max(x, NaN)` are NaN): the vector
    /// max/min, the dense rows with and without ReLU in both accumulations, the pooling's
    /// running maximum and `finish`, and the LSTM step. A NaN pair is put first, in the middle
    /// and last in its query's pair list, since a running maximum that drops a NaN only keeps
    /// it when it comes last. Every path gives the same bits.
    #[test]
    fn non_finite_values_propagate_through_vector_max_and_min() {
        // Vector max/min on every ordered pair of special values.
        struct MaxMin<'a> {
            a: &'a [f32],
            b: &'a [f32],
        }
        impl Kernel for MaxMin<'_> {
            type Out = Vec<[u32; 2]>;
            #[inline(always)]
            fn run<S: Simd>(self, s: S) -> Self::Out {
                let mut out = Vec::new();
                for (a, b) in self.a.chunks_exact(LANES).zip(self.b.chunks_exact(LANES)) {
                    let (va, vb) = (s.load(a.try_into().unwrap()), s.load(b.try_into().unwrap()));
                    let (mut mx, mut mn) = ([0.0f32; LANES], [0.0f32; LANES]);
                    s.store(s.max(va, vb), &mut mx);
                    s.store(s.min(va, vb), &mut mn);
                    out.extend((0..LANES).map(|l| [mx[l].to_bits(), mn[l].to_bits()]));
                }
                out
            }
        }
        let special = [
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            1.0,
            -1.0,
            3e38,
            -3e38,
        ];
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for &x in &special {
            for &y in &special {
                a.push(x);
                b.push(y);
            }
        }
        while a.len() % LANES != 0 {
            a.push(f32::NAN);
            b.push(2.0);
        }
        let mut first: Option<Vec<[u32; 2]>> = None;
        for isa in isas() {
            let p = isa.path();
            let got = isa.run(MaxMin { a: &a, b: &b });
            for ((&x, &y), [mx, mn]) in a.iter().zip(&b).zip(&got) {
                let (mx, mn) = (f32::from_bits(*mx), f32::from_bits(*mn));
                let (x64, y64) = (f64::from(x), f64::from(y));
                assert!(
                    agrees(mx, ieee_max(x64, y64), 0.0),
                    "{p}: max({x}, {y}) = {mx}"
                );
                assert!(
                    agrees(mn, ieee_min(x64, y64), 0.0),
                    "{p}: min({x}, {y}) = {mn}"
                );
                assert_eq!(
                    max_nan(x, y).to_bits(),
                    mx.to_bits(),
                    "{p}: scalar max bits"
                );
            }
            match &first {
                None => first = Some(got),
                Some(f) => assert_eq!(f, &got, "{p}: max/min bits differ between paths"),
            }
        }
    }

    /// NaN and ±inf through the dense rows, with and without ReLU, in both accumulations.
    #[test]
    fn non_finite_values_propagate_through_the_dense_rows() {
        // Dense rows: row 1 holds a NaN, row 3 +inf, row 5 -inf, the others are finite.
        let (out, inp, m) = (20, 7, 7);
        let w = values(31, out * inp);
        let bias = values(32, out);
        let mut x = values(33, m * inp);
        x[inp + 4] = f32::NAN;
        x[3 * inp] = f32::INFINITY;
        x[5 * inp + 6] = f32::NEG_INFINITY;
        for acc in [Accumulate::F32, Accumulate::F64] {
            let d = Dense::new(&w, &bias, out, inp, acc);
            let mut first: Option<Vec<u32>> = None;
            for isa in isas() {
                let mut bits = Vec::new();
                for relu in [false, true] {
                    let mut y = vec![0.0f32; m * out];
                    d.rows(isa, &x, inp, m, &mut y, out, relu);
                    for r in 0..m {
                        for o in 0..out {
                            let mut e = f64::from(bias[o]);
                            for k in 0..inp {
                                e += f64::from(w[o * inp + k]) * f64::from(x[r * inp + k]);
                            }
                            if relu {
                                e = ieee_relu(e);
                            }
                            let g = y[r * out + o];
                            assert!(agrees(g, e, 1e-5), "{} row {r}: {g} vs {e}", isa.path());
                        }
                    }
                    assert!(y[out..2 * out].iter().all(|v| v.is_nan()), "the NaN row");
                    bits.extend(y.iter().map(|v| v.to_bits()));
                }
                if isa.path().is_fused() {
                    match &first {
                        None => first = Some(bits),
                        Some(f) => assert_eq!(f, &bits, "fused paths differ"),
                    }
                }
            }
        }
    }

    /// NaN through the pooling's running maximum and `finish` on every path.
    #[test]
    fn non_finite_values_propagate_through_the_pooling() {
        // Pooling: the pair (query 2, neighbour 3) has a NaN offset; its query's pooled vector
        // is NaN wherever that pair comes in the list, every other query's is finite.
        let (e, h, p, bd, n) = (6, 5, 24, 18, 5);
        let emb_w = values(41, e * 2);
        let emb_b = values(42, e);
        let w1: Vec<f32> = values(43, p * (e + h)).iter().map(|v| v * 0.3).collect();
        let b1 = values(44, p);
        let w2: Vec<f32> = values(45, bd * p).iter().map(|v| v * 0.3).collect();
        let b2 = values(46, bd);
        let hs = values(47, n * h);
        let pos: Vec<f32> = values(48, n * 2).iter().map(|v| v * 30.0).collect();
        let offset = |i: usize, j: usize| {
            if (i, j) == (2, 3) {
                [f32::NAN, pos[2 * j + 1] - pos[2 * i + 1]]
            } else {
                [pos[2 * j] - pos[2 * i], pos[2 * j + 1] - pos[2 * i + 1]]
            }
        };
        // The f64 truth, literal (embed, concatenate, two layers, max), NaN-propagating.
        let want: Vec<f64> = (0..n)
            .flat_map(|i| {
                let mut best = vec![f64::NEG_INFINITY; bd];
                for j in 0..n {
                    let dd = offset(i, j);
                    let mut xx: Vec<f64> = (0..e)
                        .map(|k| {
                            f64::from(emb_w[2 * k]) * f64::from(dd[0])
                                + f64::from(emb_w[2 * k + 1]) * f64::from(dd[1])
                                + f64::from(emb_b[k])
                        })
                        .collect();
                    xx.extend(hs[j * h..(j + 1) * h].iter().map(|&v| f64::from(v)));
                    let h1: Vec<f64> = (0..p)
                        .map(|r| {
                            let row = &w1[r * (e + h)..(r + 1) * (e + h)];
                            let v: f64 = row.iter().zip(&xx).map(|(a, b)| f64::from(*a) * b).sum();
                            ieee_relu(v + f64::from(b1[r]))
                        })
                        .collect();
                    for (o, mx) in best.iter_mut().enumerate() {
                        let row = &w2[o * p..(o + 1) * p];
                        let v: f64 = row.iter().zip(&h1).map(|(a, b)| f64::from(*a) * b).sum();
                        *mx = ieee_max(*mx, ieee_relu(v + f64::from(b2[o])));
                    }
                }
                best
            })
            .collect();
        assert!(want[2 * bd..3 * bd].iter().all(|v| v.is_nan()));
        assert!(want.iter().filter(|v| v.is_finite()).count() == (n - 1) * bd);
        for acc in [Accumulate::F32, Accumulate::F64] {
            let pool = Pool::new(
                [&emb_w, &emb_b, &w1, &b1, &w2, &b2].map(Vec::as_slice),
                h,
                acc,
            );
            let (ts, al) = (pool.term_stride(), pool.acc_len());
            let mut val = vec![0.0f32; pool.val_len()];
            let mut first: Option<Vec<u32>> = None;
            for isa in isas() {
                let mut terms = vec![0.0f32; n * ts];
                pool.terms(isa, &hs, h, n, &mut terms);
                // Query 2's NaN pair (j = 3) first, in the middle, last.
                for order in [[3, 0, 1, 2, 4], [0, 1, 3, 2, 4], [0, 1, 2, 4, 3]] {
                    let pairs: Vec<Pair> = (0..n)
                        .flat_map(|i| order.iter().map(move |&j| (i, j)))
                        .map(|(i, j)| Pair {
                            q: i as u32,
                            j: j as u32,
                            d: offset(i, j),
                        })
                        .collect();
                    let mut acc = vec![0.0f32; n * al];
                    pool.reset(&mut acc, 0..n);
                    pool.fold(isa, &pairs, &terms, &mut acc, &mut val);
                    let mut got = vec![0.0f32; n * bd];
                    for i in 0..n {
                        pool.finish(&acc[i * al..], &mut got[i * bd..(i + 1) * bd]);
                    }
                    for (k, (&g, &wv)) in got.iter().zip(&want).enumerate() {
                        assert!(
                            agrees(g, wv, 1e-4),
                            "{}: order {order:?}, query {}, output {}: {g} vs {wv}",
                            isa.path(),
                            k / bd,
                            k % bd
                        );
                    }
                    if order[0] == 3 {
                        let bits: Vec<u32> = got.iter().map(|v| v.to_bits()).collect();
                        if isa.path().is_fused() {
                            match &first {
                                None => first = Some(bits),
                                Some(f) => assert_eq!(f, &bits, "fused paths differ"),
                            }
                        }
                    }
                }
            }
        }
    }

    /// NaN and ±inf through the LSTM step on every path (see the first of these tests).
    #[test]
    fn non_finite_values_propagate_through_the_lstm_step() {
        // LSTM step: row 1's cell state and row 3's displacement are NaN, row 4's hidden
        // state holds +inf; the f64 LSTM equations say which outputs are NaN.
        let (h, e, m) = (20, 5, 6);
        let emb_w = values(51, e * 2);
        let emb_b = values(52, e);
        let w_ih: Vec<f32> = values(53, 4 * h * e).iter().map(|v| v * 0.5).collect();
        let w_hh: Vec<f32> = values(54, 4 * h * h).iter().map(|v| v * 0.5).collect();
        let b_ih = values(55, 4 * h);
        let b_hh = values(56, 4 * h);
        for fused in [true, false] {
            let t = [&emb_w, &emb_b, &w_ih, &w_hh, &b_ih, &b_hh].map(Vec::as_slice);
            let lstm = Lstm::with_cell(t, h, Accumulate::F32, fused);
            let rl = lstm.row_len();
            let mut xh0 = values(57, m * rl);
            let mut c0 = values(58, m * h);
            c0[h + 7] = f32::NAN;
            xh0[3 * rl] = f32::NAN;
            xh0[4 * rl + 2 + 5] = f32::INFINITY;
            let sig = |v: f64| 1.0 / (1.0 + (-v).exp());
            let mut want_h = vec![0.0f64; m * h];
            for r in 0..m {
                let xr: Vec<f64> = xh0[r * rl..(r + 1) * rl]
                    .iter()
                    .map(|&v| f64::from(v))
                    .collect();
                let emb: Vec<f64> = (0..e)
                    .map(|k| {
                        f64::from(emb_w[2 * k]) * xr[0]
                            + f64::from(emb_w[2 * k + 1]) * xr[1]
                            + f64::from(emb_b[k])
                    })
                    .collect();
                let gate = |row: usize| {
                    let mut v = f64::from(b_ih[row]) + f64::from(b_hh[row]);
                    for k in 0..e {
                        v += f64::from(w_ih[row * e + k]) * emb[k];
                    }
                    for k in 0..h {
                        v += f64::from(w_hh[row * h + k]) * xr[2 + k];
                    }
                    v
                };
                for u in 0..h {
                    let (i, f) = (sig(gate(u)), sig(gate(h + u)));
                    let (gg, o) = (gate(2 * h + u).tanh(), sig(gate(3 * h + u)));
                    let cn = f * f64::from(c0[r * h + u]) + i * gg;
                    want_h[r * h + u] = o * cn.tanh();
                }
            }
            assert!(want_h[3 * h..4 * h].iter().all(|v| v.is_nan()));
            assert!(want_h[h + 7].is_nan() && want_h[h + 6].is_finite());
            for isa in isas() {
                let (mut xh, mut c) = (xh0.clone(), c0.clone());
                let mut g = vec![0.0f32; lstm.gates_len(m)];
                lstm.step(isa, &mut xh, rl, &mut c, &mut g, m);
                for r in 0..m {
                    for u in 0..h {
                        let (got, wv) = (xh[r * rl + 2 + u], want_h[r * h + u]);
                        assert!(
                            agrees(got, wv, 1e-5),
                            "{} fused {fused}: row {r} unit {u}: {got} vs {wv}",
                            isa.path()
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn peak_loop_counts_its_work() {
        for isa in isas() {
            let (macs, sum) = isa.run(PeakLoop {
                iterations: 1000,
                a: 0.999,
            });
            assert!(macs >= 1000 * 48, "{}", isa.path());
            assert!(sum.is_finite() && sum > 0.0);
        }
    }
}
