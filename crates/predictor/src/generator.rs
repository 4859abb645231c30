//! The Social-GAN generator shared by the teacher and the student, in f32, split into the
//! stages the two predictors cache differently.
//!
//! Layouts (row-major): windows `[n, T_OBS, 2]` and positions `[n, 2]` in f64 metres
//! (absolute); hidden states `[n, H]` in f32. Positions stay in f64 and only differences
//! (displacements, offsets between agents) enter the f32 networks: each is then rounded once,
//! relative to its own small magnitude, and predicted positions accumulate without f32
//! rounding of absolute coordinates.

use crate::T_OBS;
use crate::nn::{Dense, Lstm, Mlp2, Pool};
use crate::weights::{ModelConfig, ModelWeights};

/// The loaded, repacked generator.
#[derive(Debug, Clone)]
pub(crate) struct Generator {
    pub(crate) cfg: ModelConfig,
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

/// Scratch of one LSTM step: gates `[4H]` (padded), cell state `[H]`.
#[derive(Debug, Clone, Default)]
pub(crate) struct LstmScratch {
    pub(crate) g: Vec<f32>,
    pub(crate) c: Vec<f32>,
}

/// Scratch of the pooling: running max `[acc_len]`, first-layer compaction `[P]`.
#[derive(Debug, Clone, Default)]
pub(crate) struct PoolScratch {
    pub(crate) acc: Vec<f32>,
    pub(crate) idx: Vec<u32>,
    pub(crate) val: Vec<f32>,
}

/// Reusable buffers of one predictor, grown (never shrunk) to the scene size in `set_scene`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Scratch {
    pub(crate) ls: LstmScratch,
    pub(crate) ps: PoolScratch,
    /// Encoder final hidden states `[n, He]`.
    pub(crate) h_enc: Vec<f32>,
    /// Pool agent terms `[n, P]`.
    pub(crate) terms: Vec<f32>,
    /// Pooled vectors `[n, B]`.
    pub(crate) pooled: Vec<f32>,
    /// mlp input `[H + B]` and hidden layer.
    pub(crate) cat: Vec<f32>,
    pub(crate) hid: Vec<f32>,
    /// mlp output (padded).
    pub(crate) mout: Vec<f32>,
    /// Decoder states `[n, Hd]`.
    pub(crate) h: Vec<f32>,
    pub(crate) cd: Vec<f32>,
    /// hidden2pos output (padded).
    pub(crate) dp: Vec<f32>,
}

pub(crate) fn grow<T: Copy + Default>(v: &mut Vec<T>, len: usize) {
    if v.len() < len {
        v.resize(len, T::default());
    }
}

impl Generator {
    /// Builds the fast generator from validated weights.
    pub(crate) fn new(w: &ModelWeights) -> Self {
        let cfg = w.config().clone();
        let (he, hd) = (cfg.encoder_h_dim, cfg.decoder_h_dim);
        let enc = Lstm::new(
            w.get("encoder.spatial_embedding.weight"),
            w.get("encoder.spatial_embedding.bias"),
            w.get("encoder.encoder.weight_ih_l0"),
            w.get("encoder.encoder.weight_hh_l0"),
            w.get("encoder.encoder.bias_ih_l0"),
            w.get("encoder.encoder.bias_hh_l0"),
            he,
        );
        let pool = Pool::new(
            w.get("pool_net.spatial_embedding.weight"),
            w.get("pool_net.spatial_embedding.bias"),
            w.get("pool_net.mlp_pre_pool.0.weight"),
            w.get("pool_net.mlp_pre_pool.0.bias"),
            w.get("pool_net.mlp_pre_pool.2.weight"),
            w.get("pool_net.mlp_pre_pool.2.bias"),
            he,
        );
        let ctx = Mlp2::new(
            w.get("mlp_decoder_context.0.weight"),
            w.get("mlp_decoder_context.0.bias"),
            w.get("mlp_decoder_context.2.weight"),
            w.get("mlp_decoder_context.2.bias"),
            he + cfg.bottleneck_dim,
        );
        let dec = Lstm::new(
            w.get("decoder.spatial_embedding.weight"),
            w.get("decoder.spatial_embedding.bias"),
            w.get("decoder.decoder.weight_ih_l0"),
            w.get("decoder.decoder.weight_hh_l0"),
            w.get("decoder.decoder.bias_ih_l0"),
            w.get("decoder.decoder.bias_hh_l0"),
            hd,
        );
        let h2p = Dense::new(
            w.get("decoder.hidden2pos.weight"),
            w.get("decoder.hidden2pos.bias"),
            2,
            hd,
        );
        let (dec_pool, dec_mlp) = if cfg.pool_every_timestep {
            (
                Some(Pool::new(
                    w.get("decoder.pool_net.spatial_embedding.weight"),
                    w.get("decoder.pool_net.spatial_embedding.bias"),
                    w.get("decoder.pool_net.mlp_pre_pool.0.weight"),
                    w.get("decoder.pool_net.mlp_pre_pool.0.bias"),
                    w.get("decoder.pool_net.mlp_pre_pool.2.weight"),
                    w.get("decoder.pool_net.mlp_pre_pool.2.bias"),
                    hd,
                )),
                Some(Mlp2::new(
                    w.get("decoder.mlp.0.weight"),
                    w.get("decoder.mlp.0.bias"),
                    w.get("decoder.mlp.2.weight"),
                    w.get("decoder.mlp.2.bias"),
                    hd + cfg.bottleneck_dim,
                )),
            )
        } else {
            (None, None)
        };
        let fixed_noise = if cfg.noise_dim > 0 {
            w.get("fixed_noise").to_vec()
        } else {
            Vec::new()
        };
        let mut enc_h1 = vec![0.0f32; he];
        let mut enc_c1 = vec![0.0f32; he];
        let mut g = vec![0.0f32; enc.scratch_len()];
        enc.step([0.0, 0.0], &mut enc_h1, &mut enc_c1, &mut g);
        Self {
            cfg,
            enc,
            enc_h1,
            enc_c1,
            pool,
            ctx,
            dec,
            h2p,
            dec_pool,
            dec_mlp,
            fixed_noise,
        }
    }

    /// Grows `s` for scenes of `n` agents.
    pub(crate) fn reserve(&self, s: &mut Scratch, n: usize) {
        let (he, hd, b) = (
            self.cfg.encoder_h_dim,
            self.cfg.decoder_h_dim,
            self.cfg.bottleneck_dim,
        );
        grow(
            &mut s.ls.g,
            self.enc.scratch_len().max(self.dec.scratch_len()),
        );
        grow(&mut s.ls.c, he.max(hd));
        grow(&mut s.h_enc, n * he);
        let mut p = self.pool.hidden();
        let mut acc = self.pool.acc_len();
        let mut hid = self.ctx.hidden_len();
        if let (Some(dp), Some(dm)) = (&self.dec_pool, &self.dec_mlp) {
            p = p.max(dp.hidden());
            acc = acc.max(dp.acc_len());
            hid = hid.max(dm.hidden_len());
        }
        grow(&mut s.terms, n * p);
        grow(&mut s.ps.acc, acc);
        grow(&mut s.ps.idx, p);
        grow(&mut s.ps.val, p);
        grow(&mut s.pooled, n * b);
        grow(&mut s.cat, he.max(hd) + b);
        grow(&mut s.hid, hid);
        grow(&mut s.mout, 2 * hd + 32);
        grow(&mut s.h, n * hd);
        grow(&mut s.cd, n * hd);
        grow(&mut s.dp, 32);
    }

    /// Encoder final hidden state of agent `a` of window `win` (`[n, T_OBS, 2]`, metres)
    /// into `h_enc[a]` (`h_enc` is `[n, He]`); the first displacement is 0 as in training.
    pub(crate) fn encode_agent(
        &self,
        win: &[f64],
        a: usize,
        h_enc: &mut [f32],
        ls: &mut LstmScratch,
    ) {
        let he = self.cfg.encoder_h_dim;
        let w = &win[a * T_OBS * 2..(a + 1) * T_OBS * 2];
        let h = &mut h_enc[a * he..(a + 1) * he];
        h.copy_from_slice(&self.enc_h1);
        let c = &mut ls.c[..he];
        c.copy_from_slice(&self.enc_c1);
        for t in 1..T_OBS {
            let d = [
                (w[2 * t] - w[2 * t - 2]) as f32,
                (w[2 * t + 1] - w[2 * t - 1]) as f32,
            ];
            self.enc.step(d, h, c, &mut ls.g);
        }
    }

    /// Pool agent term of agent `a` from hidden states `hs` (`[n, H]`) into `terms[a]`
    /// (`terms` is `[n, P]`).
    pub(crate) fn pool_term(pool: &Pool, hs: &[f32], hdim: usize, a: usize, terms: &mut [f32]) {
        let p = pool.hidden();
        pool.agent_term(
            &hs[a * hdim..(a + 1) * hdim],
            &mut terms[a * p..(a + 1) * p],
        );
    }

    /// Folds agents `js` into the running max `ps.acc` of query agent `i`; `pos` is `[n, 2]`
    /// metres, `terms` `[n, P]`.
    #[inline]
    pub(crate) fn pool_fold(
        pool: &Pool,
        pos: &[f64],
        terms: &[f32],
        i: usize,
        js: std::ops::Range<usize>,
        ps: &mut PoolScratch,
    ) {
        let p = pool.hidden();
        let (xi, yi) = (pos[2 * i], pos[2 * i + 1]);
        for j in js {
            let d = [(pos[2 * j] - xi) as f32, (pos[2 * j + 1] - yi) as f32];
            pool.pair(
                d,
                &terms[j * p..(j + 1) * p],
                &mut ps.acc,
                &mut ps.idx,
                &mut ps.val,
            );
        }
    }

    /// Pooling over all `n` agents at positions `pos` (`[n, 2]`) with agent terms `terms`
    /// (`[n, P]`): `pooled[i] = relu(max_j u_ij + b2)` for the query agents `queries`.
    pub(crate) fn pool_all(
        pool: &Pool,
        pos: &[f64],
        terms: &[f32],
        n: usize,
        queries: std::ops::Range<usize>,
        ps: &mut PoolScratch,
        pooled: &mut [f32],
    ) {
        let b = pool.out_dim();
        for i in queries {
            Pool::reset(&mut ps.acc);
            Self::pool_fold(pool, pos, terms, i, 0..n, ps);
            pool.finish(&ps.acc, &mut pooled[i * b..(i + 1) * b]);
        }
    }

    /// Decoder initial hidden state of agent `i`: `[ctx_mlp([h_enc_i ; pooled_i]) ; z]` into
    /// `h0` (`[Hd]`); `h_enc` is `[n, He]`, the pooled vectors are in `s.pooled`.
    pub(crate) fn context(
        &self,
        i: usize,
        h_enc: &[f32],
        z: &[f32],
        s: &mut Scratch,
        h0: &mut [f32],
    ) {
        let (he, b) = (self.cfg.encoder_h_dim, self.cfg.bottleneck_dim);
        s.cat[..he].copy_from_slice(&h_enc[i * he..(i + 1) * he]);
        s.cat[he..he + b].copy_from_slice(&s.pooled[i * b..(i + 1) * b]);
        self.ctx.forward(&s.cat, &mut s.hid, &mut s.mout);
        let m = self.ctx.out_dim();
        h0[..m].copy_from_slice(&s.mout[..m]);
        h0[m..m + z.len()].copy_from_slice(z);
    }

    /// One decoder LSTM step of agent `i` on displacement `d`, states in `s.h`/`s.cd`;
    /// returns the predicted displacement Δp (metres).
    #[inline]
    pub(crate) fn decode_step(&self, i: usize, d: [f32; 2], s: &mut Scratch) -> [f32; 2] {
        let hd = self.cfg.decoder_h_dim;
        let h = &mut s.h[i * hd..(i + 1) * hd];
        let c = &mut s.cd[i * hd..(i + 1) * hd];
        self.dec.step(d, h, c, &mut s.ls.g);
        self.h2p.forward(h, &mut s.dp);
        [s.dp[0], s.dp[1]]
    }

    /// Decoder refinement after a step: `h_i = dec_mlp([h_i ; pooled_i])` for every agent
    /// (requires `pool_every_timestep`; `s.pooled` filled).
    pub(crate) fn refine_all(&self, n: usize, s: &mut Scratch) {
        let Some(mlp) = &self.dec_mlp else { return };
        let (hd, b) = (self.cfg.decoder_h_dim, self.cfg.bottleneck_dim);
        for i in 0..n {
            s.cat[..hd].copy_from_slice(&s.h[i * hd..(i + 1) * hd]);
            s.cat[hd..hd + b].copy_from_slice(&s.pooled[i * b..(i + 1) * b]);
            mlp.forward(&s.cat, &mut s.hid, &mut s.mout);
            s.h[i * hd..(i + 1) * hd].copy_from_slice(&s.mout[..hd]);
        }
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
        let hd = self.cfg.decoder_h_dim;
        let mut h0 = std::mem::take(&mut s.h);
        for i in 1..n {
            self.context(i, h_enc, z, s, &mut h0[i * hd..(i + 1) * hd]);
        }
        s.h = h0;
        s.cd[..n * hd].fill(0.0);
        for i in 1..n {
            let k = (i * T_OBS + T_OBS - 1) * 2;
            let d = [
                (win[k] - win[k - 2]) as f32,
                (win[k + 1] - win[k - 1]) as f32,
            ];
            let dp = self.decode_step(i, d, s);
            q[2 * i] = win[k] + f64::from(dp[0]);
            q[2 * i + 1] = win[k + 1] + f64::from(dp[1]);
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
        for a in 0..n {
            self.encode_agent(win, a, &mut h_enc, &mut s.ls);
        }
        // Positions at the last observed step, contiguous for the pooling.
        for a in 0..n {
            let k = (a * T_OBS + T_OBS - 1) * 2;
            q[2 * a] = win[k];
            q[2 * a + 1] = win[k + 1];
        }
        for a in 0..n {
            Self::pool_term(&self.pool, &h_enc, he, a, &mut s.terms);
        }
        // The ego's own pooled vector is not needed (its prediction is replaced).
        Self::pool_all(&self.pool, q, &s.terms, n, 1..n, &mut s.ps, &mut s.pooled);
        self.decode_one(win, n, &h_enc, z, s, q);
        s.h_enc = h_enc;
    }
}
