//! f32 building blocks of the fast networks: packed linear layers, an LSTM cell with the
//! spatial embedding folded into its input weights, and the split pooling module.
//!
//! Weights are repacked at load time into blocks of `BW` output rows stored input-major
//! (`[n_blocks][in][BW]`), so a matrix-vector product is a sequence of `BW`-wide
//! multiply-adds into a register-resident accumulator: every output sums its terms in input
//! order (deterministic, no reassociation), and the compiler vectorises over the outputs.

/// `a * b + c`, fused (one rounding) when the build targets FMA hardware
/// (e.g. `-C target-cpu=x86-64-v3`), two operations otherwise. The choice is made at compile
/// time, so results are reproducible for a given build.
#[inline(always)]
fn fmadd(a: f32, b: f32, c: f32) -> f32 {
    if cfg!(target_feature = "fma") {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

/// Block width for a layer with `out` outputs. 16 lanes (4 SSE / 2 AVX registers) is the
/// widest block LLVM reliably keeps in registers and vectorises; 32 was measured to fall back
/// to scalar code (2-3x more instructions).
fn pick_bw(out: usize) -> usize {
    if out > 8 { 16 } else { 8 }
}

/// Packs a row-major `[out, in]` matrix into `[ceil(out/BW)][in]` rows of `BW` lanes, zero
/// padded.
fn pack<const BW: usize>(w: &[f32], out_dim: usize, in_dim: usize) -> Vec<[f32; BW]> {
    let nblk = out_dim.div_ceil(BW);
    let mut p = vec![[0.0f32; BW]; nblk * in_dim];
    for o in 0..out_dim {
        let (blk, l) = (o / BW, o % BW);
        for k in 0..in_dim {
            p[blk * in_dim + k][l] = w[o * in_dim + k];
        }
    }
    p
}

/// Packed rows of one of the two block widths.
#[derive(Debug, Clone)]
enum Rows {
    /// 16-lane blocks.
    R16(Vec<[f32; 16]>),
    /// 8-lane blocks.
    R8(Vec<[f32; 8]>),
}

impl Rows {
    fn pack(w: &[f32], out_dim: usize, in_dim: usize) -> Self {
        if pick_bw(out_dim) == 16 {
            Self::R16(pack::<16>(w, out_dim, in_dim))
        } else {
            Self::R8(pack::<8>(w, out_dim, in_dim))
        }
    }

    /// Total lanes (padded output count times rows per block).
    fn lanes(&self) -> usize {
        match self {
            Self::R16(r) => 16 * r.len(),
            Self::R8(r) => 8 * r.len(),
        }
    }
}

/// `y = W x + b` with `W` `[out, in]`, repacked for vectorised evaluation.
#[derive(Debug, Clone)]
pub(crate) struct Dense {
    in_dim: usize,
    out_dim: usize,
    /// `[n_blocks][in]` rows of `BW` lanes.
    w: Rows,
    /// `[n_blocks]` bias blocks, zero padded (same width as `w`).
    b: Rows,
}

impl Dense {
    /// From a row-major `[out, in]` weight and an `[out]` bias.
    pub(crate) fn new(w: &[f32], b: &[f32], out_dim: usize, in_dim: usize) -> Self {
        debug_assert_eq!(w.len(), out_dim * in_dim);
        debug_assert_eq!(b.len(), out_dim);
        Self {
            in_dim,
            out_dim,
            w: Rows::pack(w, out_dim, in_dim),
            b: Rows::pack(b, out_dim, 1),
        }
    }

    /// Output size.
    pub(crate) fn out_dim(&self) -> usize {
        self.out_dim
    }

    /// Output size rounded up to whole blocks (scratch length for outputs).
    pub(crate) fn padded_out(&self) -> usize {
        self.b.lanes()
    }

    /// `y[..out] = W x[..in] + b`.
    #[inline(always)]
    pub(crate) fn forward(&self, x: &[f32], y: &mut [f32]) {
        let x = &x[..self.in_dim];
        match (&self.w, &self.b) {
            (Rows::R16(w), Rows::R16(b)) => fwd::<16>(w, b, self.in_dim, self.out_dim, x, y),
            (Rows::R8(w), Rows::R8(b)) => fwd::<8>(w, b, self.in_dim, self.out_dim, x, y),
            _ => unreachable!("weights and bias are packed with the same width"),
        }
    }

    /// `y[..out] = W [d ; h] + b` for a layer whose input is a 2-vector followed by `h`
    /// (same sums, in the same order, as [`Dense::forward`] on the concatenation).
    #[inline]
    pub(crate) fn forward_dh(&self, d: [f32; 2], h: &[f32], y: &mut [f32]) {
        debug_assert_eq!(2 + h.len(), self.in_dim);
        match (&self.w, &self.b) {
            (Rows::R16(w), Rows::R16(b)) => fwd_dh::<16>(w, b, self.in_dim, self.out_dim, d, h, y),
            (Rows::R8(w), Rows::R8(b)) => fwd_dh::<8>(w, b, self.in_dim, self.out_dim, d, h, y),
            _ => unreachable!("weights and bias are packed with the same width"),
        }
    }

    /// `y[..out] = relu(W x[..in] + b)`.
    #[inline(always)]
    pub(crate) fn forward_relu(&self, x: &[f32], y: &mut [f32]) {
        self.forward(x, y);
        relu(&mut y[..self.out_dim]);
    }
}

#[inline(always)]
fn fwd<const BW: usize>(
    w: &[[f32; BW]],
    b: &[[f32; BW]],
    in_dim: usize,
    out_dim: usize,
    x: &[f32],
    y: &mut [f32],
) {
    for (blk, (bias, block)) in b.iter().zip(w.chunks_exact(in_dim)).enumerate() {
        let mut acc = *bias;
        for (&xk, row) in x.iter().zip(block) {
            for l in 0..BW {
                acc[l] = fmadd(xk, row[l], acc[l]);
            }
        }
        store(&acc, y, blk * BW, out_dim);
    }
}

#[inline(always)]
fn fwd_dh<const BW: usize>(
    w: &[[f32; BW]],
    b: &[[f32; BW]],
    in_dim: usize,
    out_dim: usize,
    d: [f32; 2],
    h: &[f32],
    y: &mut [f32],
) {
    for (blk, (bias, block)) in b.iter().zip(w.chunks_exact(in_dim)).enumerate() {
        let mut acc = *bias;
        let (head, tail) = block.split_at(2);
        for (&xk, row) in d.iter().zip(head) {
            for l in 0..BW {
                acc[l] = fmadd(xk, row[l], acc[l]);
            }
        }
        for (&xk, row) in h.iter().zip(tail) {
            for l in 0..BW {
                acc[l] = fmadd(xk, row[l], acc[l]);
            }
        }
        store(&acc, y, blk * BW, out_dim);
    }
}

/// Writes block `acc` at `y[start..]`: the whole block when `y` has room for it (a
/// fixed-size copy; the padded outputs are exact zeros), else only the real outputs.
#[inline(always)]
fn store<const BW: usize>(acc: &[f32; BW], y: &mut [f32], start: usize, out_dim: usize) {
    if let Some(dst) = y.get_mut(start..start + BW) {
        dst.copy_from_slice(acc);
    } else {
        let n = out_dim - start;
        y[start..start + n].copy_from_slice(&acc[..n]);
    }
}

/// In-place ReLU.
#[inline]
pub(crate) fn relu(x: &mut [f32]) {
    for v in x {
        *v = v.max(0.0);
    }
}

/// `e^x` in f32 for the activations, branch-free so that loops over slices vectorise:
/// range reduction `x = n ln2 + r` (ln 2 split in two for exactness), a degree-7 polynomial
/// for `e^r` on |r| ≤ ln2/2, and `2^n` built from the exponent bits. Relative error
/// ≈ 1 ulp over the clamped range [-87, 88] (checked in the tests).
#[inline(always)]
fn exp_f32(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // 1.5 * 2^23: adding and subtracting it rounds to the nearest integer.
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let n = (x * LOG2E + ROUND) - ROUND;
    let r = fmadd(-n, LN2_LO, fmadd(-n, LN2_HI, x));
    let r2 = r * r;
    let mut p = fmadd(1.987_569_1e-4, r, 1.398_199_9e-3);
    p = fmadd(p, r, 8.333_452e-3);
    p = fmadd(p, r, 4.166_579_6e-2);
    p = fmadd(p, r, 1.666_666_5e-1);
    p = fmadd(p, r, 0.5);
    let p = fmadd(p, r2, r) + 1.0;
    // 2^n without a float-to-int conversion (which would not vectorise): n + 127 + 2^23
    // holds the biased exponent n + 127 in its low mantissa bits; shift it into place.
    let scale = f32::from_bits((n + 8_388_735.0).to_bits() << 23);
    p * scale
}

/// Logistic sigmoid `1 / (1 + e^-x)`.
#[inline(always)]
fn sigmoid_f32(x: f32) -> f32 {
    1.0 / (1.0 + exp_f32(-x))
}

/// `tanh x = 2 σ(2x) − 1`: absolute error ≈ 1e-7 (checked in the tests), the relative
/// accuracy near 0 being traded for one shared, branch-free code path.
#[inline(always)]
fn tanh_f32(x: f32) -> f32 {
    2.0 * sigmoid_f32(2.0 * x) - 1.0
}

/// One-layer LSTM cell whose input is a 2-D displacement passed through a spatial embedding
/// `Linear(2, E)`, folded into the input weights at load time:
/// `W_ih (W_e d + b_e) + b_ih + b_hh = (W_ih W_e) d + (W_ih b_e + b_ih + b_hh)`.
#[derive(Debug, Clone)]
pub(crate) struct Lstm {
    h: usize,
    /// `gates = W [d ; h] + b`, `W` `[4H, 2 + H]`, gate order i, f, g, o.
    gates: Dense,
}

impl Lstm {
    /// From the PyTorch tensors: `emb_w [E, 2]`, `emb_b [E]`, `w_ih [4H, E]`, `w_hh [4H, H]`,
    /// `b_ih`, `b_hh` `[4H]`. Folding is done in f64 and rounded once.
    pub(crate) fn new(
        emb_w: &[f32],
        emb_b: &[f32],
        w_ih: &[f32],
        w_hh: &[f32],
        b_ih: &[f32],
        b_hh: &[f32],
        h: usize,
    ) -> Self {
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
        Self {
            h,
            gates: Dense::new(&w, &b, rows, in_dim),
        }
    }

    /// Scratch size of the gates one step needs.
    pub(crate) fn scratch_len(&self) -> usize {
        self.gates.padded_out()
    }

    /// One step on displacement `d` (metres): updates `h` and `c` (`[H]` each) in place.
    /// `g` is scratch of at least [`Lstm::scratch_len`].
    #[inline]
    pub(crate) fn step(&self, d: [f32; 2], h: &mut [f32], c: &mut [f32], g: &mut [f32]) {
        let n = self.h;
        self.gates.forward_dh(d, &h[..n], g);
        // The g̃ rows were scaled by 2 at load time (exact), so one sigmoid pass serves all
        // four gates: tanh(x) = 2 σ(2x) − 1.
        let g = &mut g[..4 * n];
        for v in g.iter_mut() {
            *v = sigmoid_f32(*v);
        }
        let (gi, rest) = g.split_at(n);
        let (gf, rest) = rest.split_at(n);
        let (gg, go) = rest.split_at(n);
        let (h, c) = (&mut h[..n], &mut c[..n]);
        for k in 0..n {
            let gt = 2.0 * gg[k] - 1.0;
            let cn = fmadd(gf[k], c[k], gi[k] * gt);
            c[k] = cn;
            h[k] = go[k] * tanh_f32(cn);
        }
    }
}

/// Social-GAN's `PoolHiddenNet` with the first layer split:
/// `u_ij = relu(W2 relu(W1 [W_e (p_j - p_i) + b_e ; h_j] + b1) + b2)`, `pool_i = max_j u_ij`.
///
/// `W1 [W_e d + b_e ; h_j] + b1 = t_j + (W1e W_e) d` with the per-agent term
/// `t_j = W1h h_j + (W1e b_e + b1)` computed once per agent ([`Pool::agent_term`]); per pair
/// only two multiply-adds per hidden unit remain, then the second layer (`O(n²)` part). The
/// second layer skips the hidden units the ReLU zeroed, and its bias and ReLU are applied
/// after the max (exact: rounding is monotonic). Skipping zeros leaves every sum unchanged
/// (adding `0 · w` is exact), so the dense and sparse variants give identical results.
#[derive(Debug, Clone)]
pub(crate) struct Pool {
    p: usize,
    b: usize,
    /// `W1e W_e`, x column `[P]`.
    wpx: Vec<f32>,
    /// `W1e W_e`, y column `[P]`.
    wpy: Vec<f32>,
    /// `t_j = W1h h_j + (W1e b_e + b1)`, in = hidden size of h, out = P.
    l1h: Dense,
    /// Second layer without bias, packed `[n_blocks][P][BW2]`.
    w2: Rows,
    /// `[B]`.
    b2: Vec<f32>,
    /// Dense second layer (all P hidden units) instead of skipping the zeros: faster when
    /// fused multiply-adds are available or P is small (the skip costs a scalar compaction).
    dense: bool,
}

impl Pool {
    /// From the PyTorch tensors: `emb_w [E,2]`, `emb_b [E]`, `w1 [P, E+H]`, `b1 [P]`,
    /// `w2 [B, P]`, `b2 [B]`; `h` is the size of the pooled hidden states.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        emb_w: &[f32],
        emb_b: &[f32],
        w1: &[f32],
        b1: &[f32],
        w2: &[f32],
        b2: &[f32],
        h: usize,
    ) -> Self {
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
            wpx,
            wpy,
            l1h: Dense::new(&w1h, &c, p, h),
            w2: Rows::pack(w2, b, p),
            b2: b2.to_vec(),
            dense: cfg!(target_feature = "fma")
                || p <= DENSE_MAX_P
                || std::env::var_os("DENSE").is_some(),
        }
    }

    /// Hidden width P (length of an agent term).
    pub(crate) fn hidden(&self) -> usize {
        self.p
    }

    /// Output width B.
    pub(crate) fn out_dim(&self) -> usize {
        self.b
    }

    /// Length of a running-max accumulator (B rounded up to the block width).
    pub(crate) fn acc_len(&self) -> usize {
        self.w2.lanes() / self.p
    }

    /// Per-agent term `t_j` (`[P]`) from the agent's hidden state `h_j`.
    #[inline]
    pub(crate) fn agent_term(&self, h: &[f32], t: &mut [f32]) {
        self.l1h.forward(h, t);
    }

    /// Starts a running max (`acc` of [`Pool::acc_len`]).
    #[inline]
    pub(crate) fn reset(acc: &mut [f32]) {
        acc.fill(f32::NEG_INFINITY);
    }

    /// Folds agent `j` (offset `d = p_j - p_i` in metres, term `tj`) into agent `i`'s running
    /// max `acc`: `acc = max(acc, W2 relu(t_j + (W1e W_e) d))` (second-layer bias and ReLU come
    /// in [`Pool::finish`]). `idx`, `val` are scratch of length P.
    #[inline]
    pub(crate) fn pair(
        &self,
        d: [f32; 2],
        tj: &[f32],
        acc: &mut [f32],
        idx: &mut [u32],
        val: &mut [f32],
    ) {
        let [dx, dy] = d;
        let p = self.p;
        let (tj, wpx, wpy) = (&tj[..p], &self.wpx[..p], &self.wpy[..p]);
        let (idx, val) = (&mut idx[..p], &mut val[..p]);
        if self.dense {
            for k in 0..p {
                val[k] = fmadd(wpy[k], dy, fmadd(wpx[k], dx, tj[k])).max(0.0);
            }
            match &self.w2 {
                Rows::R16(w2) => pair_l2_dense::<16>(w2, p, val, acc),
                Rows::R8(w2) => pair_l2_dense::<8>(w2, p, val, acc),
            }
            return;
        }
        // First layer, keeping only the units the ReLU lets through (branch-free compaction).
        let mut nz = 0usize;
        for k in 0..p {
            let v = fmadd(wpy[k], dy, fmadd(wpx[k], dx, tj[k]));
            val[nz] = v;
            idx[nz] = k as u32;
            nz += usize::from(v > 0.0);
        }
        let (idx, val) = (&idx[..nz], &val[..nz]);
        match &self.w2 {
            Rows::R16(w2) => pair_l2::<16>(w2, p, idx, val, acc),
            Rows::R8(w2) => pair_l2::<8>(w2, p, idx, val, acc),
        }
    }

    /// `out[..B] = relu(acc + b2)`: the pooled vector of one agent.
    #[inline]
    pub(crate) fn finish(&self, acc: &[f32], out: &mut [f32]) {
        for k in 0..self.b {
            out[k] = (acc[k] + self.b2[k]).max(0.0);
        }
    }
}

#[inline(always)]
fn pair_l2_dense<const BW: usize>(w2: &[[f32; BW]], p: usize, val: &[f32], acc: &mut [f32]) {
    for (block, m) in w2.chunks_exact(p).zip(acc.chunks_exact_mut(BW)) {
        let mut s = [0.0f32; BW];
        for (&v, row) in val.iter().zip(block) {
            for l in 0..BW {
                s[l] = fmadd(v, row[l], s[l]);
            }
        }
        let m: &mut [f32; BW] = m.try_into().expect("chunks_exact_mut(BW) yields BW values");
        for l in 0..BW {
            m[l] = m[l].max(s[l]);
        }
    }
}

#[inline(always)]
fn pair_l2<const BW: usize>(w2: &[[f32; BW]], p: usize, idx: &[u32], val: &[f32], acc: &mut [f32]) {
    for (block, m) in w2.chunks_exact(p).zip(acc.chunks_exact_mut(BW)) {
        let mut s = [0.0f32; BW];
        for (&k, &v) in idx.iter().zip(val) {
            let row = &block[k as usize];
            for l in 0..BW {
                s[l] = fmadd(v, row[l], s[l]);
            }
        }
        let m: &mut [f32; BW] = m.try_into().expect("chunks_exact_mut(BW) yields BW values");
        for l in 0..BW {
            m[l] = m[l].max(s[l]);
        }
    }
}

/// Largest pooling width P evaluated densely without FMA hardware.
const DENSE_MAX_P: usize = 64;

/// Two-layer mlp `relu(W2 relu(W1 x + b1) + b2)`.
#[derive(Debug, Clone)]
pub(crate) struct Mlp2 {
    l1: Dense,
    l2: Dense,
}

impl Mlp2 {
    /// From `w1 [M, in]`, `b1 [M]`, `w2 [out, M]`, `b2 [out]`.
    pub(crate) fn new(w1: &[f32], b1: &[f32], w2: &[f32], b2: &[f32], in_dim: usize) -> Self {
        let m = b1.len();
        let out = b2.len();
        Self {
            l1: Dense::new(w1, b1, m, in_dim),
            l2: Dense::new(w2, b2, out, m),
        }
    }

    /// Scratch length of the hidden layer.
    pub(crate) fn hidden_len(&self) -> usize {
        self.l1.padded_out()
    }

    /// Output size.
    pub(crate) fn out_dim(&self) -> usize {
        self.l2.out_dim()
    }

    /// `y[..out] = mlp(x)`; `hid` is scratch of [`Mlp2::hidden_len`].
    #[inline]
    pub(crate) fn forward(&self, x: &[f32], hid: &mut [f32], y: &mut [f32]) {
        self.l1.forward_relu(x, hid);
        self.l2.forward_relu(hid, y);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn activations_are_accurate() {
        let mut worst_sig = 0.0f64;
        let mut worst_tanh = 0.0f64;
        let mut xs: Vec<f32> = (-400_000..=400_000).map(|i| i as f32 * 5e-5).collect();
        xs.extend([-100.0, -60.0, -30.0, 30.0, 60.0, 100.0, 1e-30, -1e-30, 0.0]);
        let s: Vec<f32> = xs.iter().map(|&x| sigmoid_f32(x)).collect();
        let t: Vec<f32> = xs.iter().map(|&x| tanh_f32(x)).collect();
        for ((&x, &sv), &tv) in xs.iter().zip(&s).zip(&t) {
            let x = f64::from(x);
            let se = 1.0 / (1.0 + (-x).exp());
            let te = x.tanh();
            worst_sig = worst_sig.max((f64::from(sv) - se).abs());
            worst_tanh = worst_tanh.max((f64::from(tv) - te).abs());
        }
        assert!(worst_sig < 1.5e-7, "sigmoid abs error {worst_sig:e}");
        assert!(worst_tanh < 2.5e-7, "tanh abs error {worst_tanh:e}");
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

    /// The split pooling equals the literal one (embed, concatenate, two layers, max) to
    /// rounding, and its dense and zero-skipping variants agree bit for bit.
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
        let mut pool = Pool::new(&emb_w, &emb_b, &w1, &b1, &w2, &b2, h);
        let dot = |w: &[f32], x: &[f32]| -> f64 {
            w.iter()
                .zip(x)
                .map(|(a, b)| f64::from(*a) * f64::from(*b))
                .sum()
        };
        let mut terms = vec![0.0f32; n * p];
        for j in 0..n {
            pool.agent_term(&hs[j * h..(j + 1) * h], &mut terms[j * p..(j + 1) * p]);
        }
        let mut results = Vec::new();
        for dense in [true, false] {
            pool.dense = dense;
            let mut out = vec![0.0f32; n * b];
            let mut acc = vec![0.0f32; pool.acc_len()];
            let (mut idx, mut val) = (vec![0u32; p], vec![0.0f32; p]);
            for i in 0..n {
                Pool::reset(&mut acc);
                for j in 0..n {
                    let d = [pos[2 * j] - pos[2 * i], pos[2 * j + 1] - pos[2 * i + 1]];
                    pool.pair(d, &terms[j * p..(j + 1) * p], &mut acc, &mut idx, &mut val);
                }
                pool.finish(&acc, &mut out[i * b..(i + 1) * b]);
            }
            results.push(out.clone());
            // Literal evaluation in f64.
            for i in 0..n {
                let mut best = vec![f64::NEG_INFINITY; b];
                for j in 0..n {
                    let d = [pos[2 * j] - pos[2 * i], pos[2 * j + 1] - pos[2 * i + 1]];
                    let mut x: Vec<f32> = (0..e)
                        .map(|k| (dot(&emb_w[2 * k..2 * k + 2], &d) + f64::from(emb_b[k])) as f32)
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
                    assert!((got - m).abs() < 1e-4 * (1.0 + m.abs()), "{got} vs {m}");
                }
            }
        }
        assert_eq!(
            results[0], results[1],
            "dense and sparse second layers differ"
        );
    }

    #[test]
    fn exp_is_accurate() {
        let mut worst = 0.0f64;
        for i in -86_900..=87_900 {
            let x = i as f32 * 1e-3;
            let e = f64::from(x).exp();
            worst = worst.max(((f64::from(exp_f32(x)) - e) / e).abs());
        }
        assert!(worst < 3e-7, "exp rel error {worst:e}");
    }
}
