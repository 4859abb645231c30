//! The Social-GAN generator shared by the teacher and the student, in f32, split into the
//! stages the two predictors cache differently. Every stage runs on a range of agents at once
//! (one matrix kernel per layer and step, see [`nn`](crate::nn)).
//!
//! Layouts (row-major): windows `[n, T_OBS, 2]` and positions `[n, 2]` in f64 metres
//! (absolute); hidden states `[n, H]` in f32, pool terms `[n, term_stride]`, running maxima
//! `[n, acc_len]`. Positions stay in f64 and only differences (displacements, offsets between
//! agents) enter the f32 networks: each is then rounded once, relative to its own small
//! magnitude, and predicted positions accumulate without f32 rounding of absolute coordinates.
//!
//! The student's decoder keeps each agent's state in one row `[d ; h ; pooled]`
//! ([`Generator::dec_row_len`] floats: input displacement, hidden state, pooled vector), which
//! the LSTM, the pooling and the refinement mlp read and write in place.

use std::ops::Range;

use crate::T_OBS;
use crate::nn::{Accumulate, Dense, Lstm, Mlp2, PairGrid, Pool};
use crate::simd::Isa;
use crate::weights::{ModelConfig, ModelKind, ModelWeights};
use crate::weights_file::{Layout, LstmModule, MlpModule, Module, PoolModule};

/// The loaded, repacked generator.
#[derive(Debug, Clone)]
pub(crate) struct Generator {
    pub(crate) cfg: ModelConfig,
    /// Instruction set every kernel runs on.
    pub(crate) isa: Isa,
    enc: Lstm,
    /// Encoder state after its first step (input displacement 0 from the zero state): the
    /// same for every agent, so computed once here. `[He]` each.
    enc_h1: Vec<f32>,
    enc_c1: Vec<f32>,
    pub(crate) pool: Pool,
    ctx: Mlp2,
    dec: Lstm,
    h2p: Dense,
    pub(crate) dec_pool: Option<Pool>,
    dec_mlp: Option<Mlp2>,
    /// The file's `fixed_noise` `[Z]` (empty when Z = 0).
    pub(crate) fixed_noise: Vec<f32>,
}

/// Reusable buffers of one predictor, grown (never shrunk) to the scene size in `set_scene`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Scratch {
    /// LSTM rows `[n, 2 + H]` (`[d ; h]`), cell states `[n, H]`, gates `[n, 4H]`.
    xh: Vec<f32>,
    c: Vec<f32>,
    g: Vec<f32>,
    /// Encoder final hidden states `[n, He]`.
    pub(crate) h_enc: Vec<f32>,
    /// Pool agent terms `[n, term_stride]`.
    pub(crate) terms: Vec<f32>,
    /// Running maxima of the pooling `[n, acc_len]`.
    pub(crate) acc: Vec<f32>,
    /// Pooled vectors `[n, B]`.
    pub(crate) pooled: Vec<f32>,
    /// First-layer rows of one pooling tile.
    val: Vec<f32>,
    /// mlp inputs `[n, H + B]` and hidden layers `[n, M]`.
    cat: Vec<f32>,
    hid: Vec<f32>,
    /// Decoder cell states `[n, Hd]` (the student's).
    pub(crate) cd: Vec<f32>,
    /// hidden2pos outputs `[n, 2]`.
    dp: Vec<f32>,
}

pub(crate) fn grow<T: Copy + Default>(v: &mut Vec<T>, len: usize) {
    if v.len() < len {
        v.resize(len, T::default());
    }
}

/// Precision of the dense layers' sums for a model kind. The teacher feeds its own
/// predictions back through six generator calls, which amplifies f32 rounding: with f32 sums
/// its error against the f64 reference reached 1.2e-5 m on the trained golden scenes, with f64
/// sums about 5e-6 m. The one-pass student stays within about 4e-6 m with f32 sums, which run
/// at twice the vector width.
fn accumulate(kind: ModelKind) -> Accumulate {
    match kind {
        ModelKind::Teacher => Accumulate::F64,
        ModelKind::Student => Accumulate::F32,
    }
}

impl Generator {
    /// Builds the fast generator from validated weights, its kernels running on `isa`.
    pub(crate) fn new(w: &ModelWeights, isa: Isa) -> Self {
        let cfg = w.config().clone();
        let he = cfg.encoder_h_dim;
        let acc = accumulate(cfg.kind);
        let l = Layout::new(&cfg);
        let lstm = |m: &LstmModule| Lstm::new(m.values(w), m.h, acc);
        let pool = |m: &PoolModule| Pool::new(m.values(w), m.h, acc);
        let mlp = |m: &MlpModule| Mlp2::new(m.values(w), m.inp, acc);
        let [h2p_w, h2p_b] = l.h2p.values(w);
        let (dec_pool, dec_mlp) = match &l.dec_pool {
            Some((p, m)) => (Some(pool(p)), Some(mlp(m))),
            None => (None, None),
        };
        let fixed_noise = l.fixed_noise(w).to_vec();
        let (enc, pool, ctx, dec) = (lstm(&l.enc), pool(&l.pool), mlp(&l.ctx), lstm(&l.dec));
        let h2p = Dense::new(h2p_w, h2p_b, l.h2p.out, l.h2p.inp, acc);
        let mut generator = Self {
            cfg,
            isa,
            enc,
            enc_h1: vec![0.0; he],
            enc_c1: vec![0.0; he],
            pool,
            ctx,
            dec,
            h2p,
            dec_pool,
            dec_mlp,
            fixed_noise,
        };
        generator.set_isa(isa);
        generator
    }

    /// Switches the instruction set (recomputes the cached first encoder step with it).
    pub(crate) fn set_isa(&mut self, isa: Isa) {
        self.isa = isa;
        let he = self.cfg.encoder_h_dim;
        let mut xh = vec![0.0f32; self.enc.row_len()];
        let mut c = vec![0.0f32; he];
        let mut g = vec![0.0f32; self.enc.gates_len(1)];
        self.enc
            .step(isa, &mut xh, self.enc.row_len(), &mut c, &mut g, 1);
        self.enc_h1.copy_from_slice(&xh[2..]);
        self.enc_c1.copy_from_slice(&c);
    }

    /// Grows `s` for scenes of `n` agents.
    pub(crate) fn reserve(&self, s: &mut Scratch, n: usize) {
        let (he, hd, b) = (
            self.cfg.encoder_h_dim,
            self.cfg.decoder_h_dim,
            self.cfg.bottleneck_dim,
        );
        grow(&mut s.xh, n * self.enc.row_len().max(self.dec.row_len()));
        grow(&mut s.c, n * he.max(hd));
        grow(&mut s.g, self.enc.gates_len(n).max(self.dec.gates_len(n)));
        grow(&mut s.h_enc, n * he);
        let pools = std::iter::once(&self.pool).chain(self.dec_pool.as_ref());
        for pool in pools {
            grow(&mut s.terms, n * pool.term_stride());
            grow(&mut s.acc, n * pool.acc_len());
            grow(&mut s.val, pool.val_len());
        }
        grow(&mut s.pooled, n * b);
        grow(&mut s.cat, n * (he.max(hd) + b));
        let mut hid = self.ctx.hidden_len(n);
        if let Some(dm) = &self.dec_mlp {
            hid = hid.max(dm.hidden_len(n));
        }
        grow(&mut s.hid, hid);
        grow(&mut s.cd, n * hd);
        grow(&mut s.dp, 2 * n);
    }

    /// Encoder final hidden states of `agents` of window `win` (`[n, T_OBS, 2]`, metres) into
    /// their rows of `h_enc` (`[n, He]`); the first displacement is 0 as in training.
    pub(crate) fn encode(
        &self,
        win: &[f64],
        agents: Range<usize>,
        h_enc: &mut [f32],
        s: &mut Scratch,
    ) {
        let (he, rl, m) = (self.cfg.encoder_h_dim, self.enc.row_len(), agents.len());
        if m == 0 {
            return;
        }
        for r in 0..m {
            s.xh[r * rl + 2..(r + 1) * rl].copy_from_slice(&self.enc_h1);
            s.c[r * he..(r + 1) * he].copy_from_slice(&self.enc_c1);
        }
        for t in 1..T_OBS {
            for (r, a) in agents.clone().enumerate() {
                let w = &win[a * T_OBS * 2..(a + 1) * T_OBS * 2];
                s.xh[r * rl] = (w[2 * t] - w[2 * t - 2]) as f32;
                s.xh[r * rl + 1] = (w[2 * t + 1] - w[2 * t - 1]) as f32;
            }
            self.enc
                .step(self.isa, &mut s.xh, rl, &mut s.c, &mut s.g, m);
        }
        for (r, a) in agents.enumerate() {
            h_enc[a * he..(a + 1) * he].copy_from_slice(&s.xh[r * rl + 2..(r + 1) * rl]);
        }
    }

    /// Pool agent terms of `agents` from their hidden states (rows of `hs`, stride `ld`) into
    /// their rows of `terms` (stride `pool.term_stride()`).
    pub(crate) fn pool_terms(
        &self,
        pool: &Pool,
        hs: &[f32],
        ld: usize,
        agents: Range<usize>,
        terms: &mut [f32],
    ) {
        if agents.is_empty() {
            return;
        }
        let ts = pool.term_stride();
        pool.terms(
            self.isa,
            &hs[agents.start * ld..],
            ld,
            agents.len(),
            &mut terms[agents.start * ts..],
        );
    }

    /// Folds the pairs `(i, j)`, `i` in `queries`, `j` in `js`, into the running maxima
    /// `s.acc` (rows by query); `pos` is `[n, 2]` metres, `terms` `[n, term_stride]`.
    pub(crate) fn pool_fold(
        &self,
        pool: &Pool,
        pos: &[f64],
        terms: &[f32],
        queries: Range<usize>,
        js: Range<usize>,
        s: &mut Scratch,
    ) {
        let grid = PairGrid { pos, queries, js };
        pool.fold_grid(self.isa, grid, terms, &mut s.acc, &mut s.val);
    }

    /// `s.pooled[i] = relu(s.acc[i] + b2)` for `i` in `queries`.
    pub(crate) fn pool_finish(pool: &Pool, queries: Range<usize>, s: &mut Scratch) {
        let b = pool.out_dim();
        Self::pool_finish_into(pool, queries, &s.acc, &mut s.pooled, b);
    }

    /// `out[i * ld..][..B] = relu(acc[i] + b2)` for `i` in `queries` (`acc` rows of
    /// `pool.acc_len()`).
    pub(crate) fn pool_finish_into(
        pool: &Pool,
        queries: Range<usize>,
        acc: &[f32],
        out: &mut [f32],
        ld: usize,
    ) {
        let (al, b) = (pool.acc_len(), pool.out_dim());
        for i in queries {
            pool.finish(&acc[i * al..(i + 1) * al], &mut out[i * ld..i * ld + b]);
        }
    }

    /// As [`Generator::pool_all`], the pooled vector of agent `i` to `out[i * ld..][..B]`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn pool_all_into(
        &self,
        pool: &Pool,
        pos: &[f64],
        terms: &[f32],
        n: usize,
        queries: Range<usize>,
        s: &mut Scratch,
        out: &mut [f32],
        ld: usize,
    ) {
        pool.reset(&mut s.acc, queries.clone());
        self.pool_fold(pool, pos, terms, queries.clone(), 0..n, s);
        Self::pool_finish_into(pool, queries, &s.acc, out, ld);
    }

    /// Pooling over all `n` agents at positions `pos` (`[n, 2]`) with agent terms `terms`
    /// (`[n, term_stride]`): `s.pooled[i] = relu(max_j u_ij + b2)` for the query agents
    /// `queries`.
    pub(crate) fn pool_all(
        &self,
        pool: &Pool,
        pos: &[f64],
        terms: &[f32],
        n: usize,
        queries: Range<usize>,
        s: &mut Scratch,
    ) {
        pool.reset(&mut s.acc, queries.clone());
        self.pool_fold(pool, pos, terms, queries.clone(), 0..n, s);
        Self::pool_finish(pool, queries, s);
    }

    /// Decoder initial hidden states of `agents`: row `r` of `out` (stride `ld`) receives
    /// `[ctx_mlp([h_enc_i ; pooled_i]) ; z]` (`[Hd]`) of agent `i = agents.start + r`;
    /// `h_enc` is `[n, He]`, the pooled vectors are in `s.pooled`.
    pub(crate) fn context(
        &self,
        agents: Range<usize>,
        h_enc: &[f32],
        z: &[f32],
        s: &mut Scratch,
        out: &mut [f32],
        ld: usize,
    ) {
        let (he, b) = (self.cfg.encoder_h_dim, self.cfg.bottleneck_dim);
        let (cl, m) = (he + b, agents.len());
        for (r, i) in agents.enumerate() {
            let row = &mut s.cat[r * cl..(r + 1) * cl];
            row[..he].copy_from_slice(&h_enc[i * he..(i + 1) * he]);
            row[he..].copy_from_slice(&s.pooled[i * b..(i + 1) * b]);
        }
        self.ctx.rows(self.isa, &s.cat, cl, m, &mut s.hid, out, ld);
        let mo = self.ctx.out_dim();
        for r in 0..m {
            out[r * ld + mo..r * ld + mo + z.len()].copy_from_slice(z);
        }
    }

    /// Length of one row of the student's decoder state `[d ; h ; pooled]`: the input
    /// displacement (2, metres), the hidden state (`Hd`) and the pooled vector (`B`), laid out
    /// so that the LSTM reads `[d ; h]`, the refinement mlp `[h ; pooled]` and the pooling `h`
    /// in place, without copies.
    pub(crate) fn dec_row_len(&self) -> usize {
        2 + self.cfg.decoder_h_dim + self.cfg.bottleneck_dim
    }

    /// One decoder step of `agents`: rows `rows[i * dec_row_len..]` (`[d ; h ; pooled]`),
    /// cell states in their rows of `s.cd`. `h` is updated and `d` is replaced by the
    /// predicted displacement Δp (metres).
    pub(crate) fn decode_rows(&self, agents: Range<usize>, rows: &mut [f32], s: &mut Scratch) {
        let (hd, ld, m) = (self.cfg.decoder_h_dim, self.dec_row_len(), agents.len());
        if m == 0 {
            return;
        }
        let rows = &mut rows[agents.start * ld..agents.end * ld];
        let cells = &mut s.cd[agents.start * hd..agents.end * hd];
        self.dec.step(self.isa, rows, ld, cells, &mut s.g, m);
        self.h2p
            .rows(self.isa, &rows[2..], ld, m, &mut s.dp, 2, false);
        for (row, dp) in rows.chunks_exact_mut(ld).zip(s.dp.chunks_exact(2)) {
            row[..2].copy_from_slice(dp);
        }
    }

    /// Decoder refinement after a step, in place: `h_i = dec_mlp([h_i ; pooled_i])` for the
    /// first `n` rows `[d ; h ; pooled]` (requires `pool_every_timestep`; pooled parts filled).
    pub(crate) fn refine_rows(&self, n: usize, rows: &mut [f32], s: &mut Scratch) {
        let Some(mlp) = &self.dec_mlp else { return };
        let ld = self.dec_row_len();
        mlp.rows_in_place(self.isa, &mut rows[2..], ld, n, &mut s.hid);
    }

    /// The teacher's decoder (`pred_len = 1`) for agents `1..n` of window `win`
    /// (`[n, T_OBS, 2]`): contexts from `h_enc` (`[n, He]`) and `s.pooled`, one LSTM step
    /// from `[ctx ; z]`, `c = 0`; next positions (metres) into `q[1..n]` (`q` is `[n, 2]`).
    /// The ego is skipped: its prediction is replaced by the candidate.
    pub(crate) fn decode_one(
        &self,
        win: &[f64],
        n: usize,
        h_enc: &[f32],
        z: &[f32],
        s: &mut Scratch,
        q: &mut [f64],
    ) {
        let (hd, rl, m) = (self.cfg.decoder_h_dim, self.dec.row_len(), n - 1);
        if m == 0 {
            return;
        }
        let mut xh = std::mem::take(&mut s.xh);
        self.context(1..n, h_enc, z, s, &mut xh[2..], rl);
        for (r, i) in (1..n).enumerate() {
            let k = (i * T_OBS + T_OBS - 1) * 2;
            xh[r * rl] = (win[k] - win[k - 2]) as f32;
            xh[r * rl + 1] = (win[k + 1] - win[k - 1]) as f32;
        }
        s.c[..m * hd].fill(0.0);
        self.dec.step(self.isa, &mut xh, rl, &mut s.c, &mut s.g, m);
        self.h2p
            .rows(self.isa, &xh[2..], rl, m, &mut s.dp, 2, false);
        s.xh = xh;
        for (r, i) in (1..n).enumerate() {
            let k = (i * T_OBS + T_OBS - 1) * 2;
            q[2 * i] = win[k] + f64::from(s.dp[2 * r]);
            q[2 * i + 1] = win[k + 1] + f64::from(s.dp[2 * r + 1]);
        }
    }

    /// One whole generator call with `pred_len = 1` (the teacher's): from window `win`
    /// (`[n, T_OBS, 2]`, metres) predicts the next position of agents `1..n` into `q`
    /// (`[n, 2]`; `q[0]` receives the ego's last position, to be replaced by the candidate).
    pub(crate) fn one_step(
        &self,
        win: &[f64],
        n: usize,
        z: &[f32],
        s: &mut Scratch,
        q: &mut [f64],
    ) {
        let he = self.cfg.encoder_h_dim;
        let mut h_enc = std::mem::take(&mut s.h_enc);
        self.encode(win, 0..n, &mut h_enc, s);
        // Positions at the last observed step, contiguous for the pooling.
        for a in 0..n {
            let k = (a * T_OBS + T_OBS - 1) * 2;
            q[2 * a] = win[k];
            q[2 * a + 1] = win[k + 1];
        }
        let mut terms = std::mem::take(&mut s.terms);
        self.pool_terms(&self.pool, &h_enc, he, 0..n, &mut terms);
        // The ego's own pooled vector is not needed (its prediction is replaced).
        self.pool_all(&self.pool, q, &terms, n, 1..n, s);
        s.terms = terms;
        self.decode_one(win, n, &h_enc, z, s, q);
        s.h_enc = h_enc;
    }
}
