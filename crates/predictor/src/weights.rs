//! Loading and validating network weights exported by `python/train` as `.safetensors`.
//!
//! A weights file holds the PyTorch `state_dict` of one generator (float32, `W` stored
//! `(out, in)` row-major) and string metadata:
//!
//! * `"config"`: the JSON [`ModelConfig`] (required);
//! * `"format"`: `"nudge.weights/1"` (optional; any other value is rejected);
//! * `"trained"`: `"true"` / `"false"` (optional, informative);
//! * `"provenance"`: free-form JSON (optional, ignored);
//! * `"sha256"`: the content hash below, 64 lowercase hex digits (required).
//!
//! **Content hash.** SHA-256 over the concatenation of these fields, each preceded by its
//! length in bytes as a u64 little endian: the format string `nudge.weights/1`; the `"config"`
//! metadata string, byte for byte as stored; then, for every tensor in ascending byte order of
//! its name: the name (UTF-8), the dtype name as safetensors writes it (`F32`), the shape
//! (here the field is the dimension count as a u64 little endian, followed by each dimension
//! as a u64 little endian) and the raw data bytes as stored (little endian). [`content_sha256`]
//! computes it; `python/train/nudge_train/export.py` (`weights_sha256`) writes it. It covers
//! everything that changes a prediction and nothing else (`trained` and `provenance` are
//! informative), and it does not depend on the file's header layout or tensor order.
//!
//! A file without the hash is refused ([`PredictorError::MissingHash`]): an optional hash would
//! let a flipped bit in the key `"sha256"` itself turn a corrupted file into an unchecked one.
//! Files from older exporters are re-stamped (tensor bytes unchanged) with the exporter's
//! `stamp_weights`.
//!
//! [`ModelWeights::from_file`] / [`ModelWeights::from_bytes`] check, in this order: the file is
//! safetensors; the config is present, valid JSON, of a known kind, has exactly the fields of
//! [`ModelConfig`] (unknown fields are **rejected**: a field the Rust side does not understand
//! could change the network, so it must not be silently ignored) and sane values; then every
//! tensor the config calls for, in [`expected_tensors`] order, exists, is F32, has the expected
//! shape and finite values; no other tensor is present; finally the content hash matches. The
//! first problem found is returned as the matching [`PredictorError`] variant naming the file
//! and tensor. [`ModelWeights::from_file`] reads only regular files of at most
//! [`MAX_WEIGHTS_BYTES`](crate::file::MAX_WEIGHTS_BYTES).

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use safetensors::{Dtype, SafeTensors};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::error::{PredictorError, Result};
use crate::{DT, MAX_HORIZON, T_OBS};

/// Value of the `"format"` metadata entry this crate reads.
pub const WEIGHTS_FORMAT: &str = "nudge.weights/1";

/// Which network a weights file holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// The large Social-GAN generator used recursively (one step per call, 6 calls).
    Teacher,
    /// The small distilled network predicting the whole horizon in one pass.
    Student,
}

impl ModelKind {
    /// `"teacher"` or `"student"`, as in the config JSON.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Teacher => "teacher",
            Self::Student => "student",
        }
    }
}

/// The network configuration stored as JSON under the `"config"` metadata key.
///
/// Mirrors the Python dataclass `ModelConfig` field for field. Sizes are element counts,
/// `dt` is seconds, step counts are 0.3 s steps. Unknown JSON fields are rejected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    /// Teacher or student.
    pub kind: ModelKind,
    /// Observed steps fed to the encoder; must equal [`T_OBS`] (8).
    pub obs_len: usize,
    /// Steps predicted by one generator call: 1 for the teacher, `t_plan` for the student.
    pub pred_len: usize,
    /// Planning horizon in steps (6): the number of predicted positions per agent.
    pub t_plan: usize,
    /// Step length in seconds; must equal [`DT`] (0.3).
    pub dt: f64,
    /// Width E of every spatial embedding `Linear(2, E)`.
    pub embedding_dim: usize,
    /// Hidden size He of the encoder LSTM.
    pub encoder_h_dim: usize,
    /// Hidden size Hd of the decoder LSTM.
    pub decoder_h_dim: usize,
    /// Hidden width M of the context (and decoder) mlp.
    pub mlp_dim: usize,
    /// Output width B of the pooling module.
    pub bottleneck_dim: usize,
    /// Hidden width P of the pooling mlp (Social-GAN's hard-coded 512).
    pub pool_hidden_dim: usize,
    /// Size Z of the noise vector appended to the decoder's initial state (0: none).
    pub noise_dim: usize,
    /// Whether the decoder pools (and refines h with its mlp) after every step.
    pub pool_every_timestep: bool,
    /// Activation of every mlp; only `"relu"` is supported.
    pub activation: String,
    /// Discriminator encoder size (training only; not used for inference).
    pub d_encoder_h_dim: usize,
    /// Discriminator mlp width (training only; not used for inference).
    pub d_mlp_dim: usize,
    /// Seed of the weight initialisation (informative).
    pub seed: u64,
    /// Seed of the stored `fixed_noise` (informative).
    pub noise_seed: u64,
}

impl ModelConfig {
    /// The shipped teacher's sizes (MODELS.md): E 16, He 32, Hd 32, M 64, B 32, P 512, Z 8,
    /// one step per call, no pooling in the decoder.
    #[must_use]
    pub fn teacher() -> Self {
        Self {
            kind: ModelKind::Teacher,
            obs_len: T_OBS,
            pred_len: 1,
            t_plan: 6,
            dt: DT,
            embedding_dim: 16,
            encoder_h_dim: 32,
            decoder_h_dim: 32,
            mlp_dim: 64,
            bottleneck_dim: 32,
            pool_hidden_dim: 512,
            noise_dim: 8,
            pool_every_timestep: false,
            activation: "relu".to_owned(),
            d_encoder_h_dim: 48,
            d_mlp_dim: 64,
            seed: 0,
            noise_seed: 1,
        }
    }

    /// The shipped student's sizes (MODELS.md): E 16, He 16, Hd 16, M 16, B 16, P 16, no
    /// noise, 6 steps per call, pooling after every decoder step.
    #[must_use]
    pub fn student() -> Self {
        Self {
            kind: ModelKind::Student,
            pred_len: 6,
            encoder_h_dim: 16,
            decoder_h_dim: 16,
            mlp_dim: 16,
            bottleneck_dim: 16,
            pool_hidden_dim: 16,
            noise_dim: 0,
            pool_every_timestep: true,
            d_encoder_h_dim: 24,
            d_mlp_dim: 16,
            ..Self::teacher()
        }
    }
}

/// A `.safetensors` image in the export format with seeded random weights for `config`:
/// every tensor uniform in ±1/√fan_in (PyTorch's default `Linear`/`LSTM` initialisation
/// range; fan_in = last dimension, 1 for vectors) and `fixed_noise` roughly standard normal.
/// For tests and benchmarks that must run without the Python side; not bit-identical to
/// PyTorch's initialisation.
///
/// # Errors
/// [`PredictorError::NotSafetensors`] if serialisation fails (it does not for valid
/// configs).
pub fn synthetic_weights(config: &ModelConfig, seed: u64) -> Result<Vec<u8>> {
    let mut state = seed ^ 0x9e37_79b9_7f4a_7c15;
    let mut next = move || {
        // splitmix64
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    };
    let tensors: Vec<(String, Vec<usize>, Vec<u8>)> = expected_tensors(config)
        .into_iter()
        .map(|(name, shape)| {
            let len: usize = shape.iter().product();
            let values: Vec<f32> = if name == FIXED_NOISE {
                // Sum of 12 uniforms minus 6: approximately N(0, 1).
                (0..len)
                    .map(|_| ((0..12).map(|_| next()).sum::<f64>() - 6.0) as f32)
                    .collect()
            } else {
                let fan_in = if shape.len() > 1 {
                    shape[shape.len() - 1]
                } else {
                    1
                };
                let bound = 1.0 / (fan_in as f64).sqrt();
                (0..len)
                    .map(|_| ((2.0 * next() - 1.0) * bound) as f32)
                    .collect()
            };
            let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
            (name, shape, bytes)
        })
        .collect();
    let views = tensors
        .iter()
        .map(|(name, shape, bytes)| {
            safetensors::tensor::TensorView::new(Dtype::F32, shape.clone(), bytes)
                .map(|v| (name.clone(), v))
        })
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(|e| PredictorError::NotSafetensors {
            path: PathBuf::from(MEMORY),
            reason: e.to_string(),
        })?;
    let config_json = serde_json::to_string(config).map_err(|e| PredictorError::BadConfig {
        path: PathBuf::from(MEMORY),
        reason: e.to_string(),
    })?;
    let hash = content_sha256(
        &config_json,
        tensors.iter().map(|(name, shape, bytes)| {
            (
                name.as_str(),
                Dtype::F32,
                shape.as_slice(),
                bytes.as_slice(),
            )
        }),
    );
    let metadata = std::collections::HashMap::from([
        ("sha256".to_owned(), hash),
        ("config".to_owned(), config_json),
        ("format".to_owned(), WEIGHTS_FORMAT.to_owned()),
        ("trained".to_owned(), "false".to_owned()),
        (
            "provenance".to_owned(),
            format!(
                "{{\"generator\":\"nudge_predictor::weights::synthetic_weights\",\"seed\":{seed}}}"
            ),
        ),
    ]);
    safetensors::serialize(views, Some(metadata)).map_err(|e| PredictorError::NotSafetensors {
        path: PathBuf::from(MEMORY),
        reason: e.to_string(),
    })
}

/// The content hash of a weights file (see the module documentation for the exact bytes):
/// `config` is the `"config"` metadata string, `tensors` yields `(name, dtype, shape, data)`
/// in any order. Returns 64 lowercase hex digits.
pub fn content_sha256<'a>(
    config: &str,
    tensors: impl IntoIterator<Item = (&'a str, Dtype, &'a [usize], &'a [u8])>,
) -> String {
    fn field(h: &mut Sha256, bytes: &[u8]) {
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(bytes);
    }
    let mut tensors: Vec<_> = tensors.into_iter().collect();
    tensors.sort_unstable_by(|a, b| a.0.as_bytes().cmp(b.0.as_bytes()));
    let mut h = Sha256::new();
    field(&mut h, WEIGHTS_FORMAT.as_bytes());
    field(&mut h, config.as_bytes());
    for (name, dtype, shape, data) in tensors {
        field(&mut h, name.as_bytes());
        field(&mut h, dtype.to_string().as_bytes());
        h.update((shape.len() as u64).to_le_bytes());
        for &d in shape {
            h.update((d as u64).to_le_bytes());
        }
        field(&mut h, data);
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// A copy of the safetensors image `bytes` with the `"sha256"` metadata entry set to its
/// content hash (tensor bytes and other metadata unchanged; the header is re-serialised). For
/// tests and tools that edit weights on purpose.
///
/// # Errors
/// [`PredictorError::NotSafetensors`] if `bytes` is not a safetensors image,
/// [`PredictorError::BadConfig`] if it has no `"config"` entry.
pub fn restamp(bytes: &[u8]) -> Result<Vec<u8>> {
    let bad = |e: safetensors::SafeTensorError| PredictorError::NotSafetensors {
        path: PathBuf::from(MEMORY),
        reason: e.to_string(),
    };
    let st = SafeTensors::deserialize(bytes).map_err(bad)?;
    let (_, header) = SafeTensors::read_metadata(bytes).map_err(bad)?;
    let mut meta = header.metadata().clone().unwrap_or_default();
    let config = meta
        .get("config")
        .ok_or_else(|| PredictorError::BadConfig {
            path: PathBuf::from(MEMORY),
            reason: "no \"config\" metadata entry".to_owned(),
        })?;
    let views = st.tensors();
    let hash = content_sha256(
        config,
        views
            .iter()
            .map(|(n, v)| (n.as_str(), v.dtype(), v.shape(), v.data())),
    );
    meta.insert("sha256".to_owned(), hash);
    safetensors::serialize(views, Some(meta)).map_err(bad)
}

/// Largest accepted size of any one dimension (guards against absurd configs).
const MAX_DIM: usize = 1 << 16;

impl ModelConfig {
    /// Checks the values the networks rely on; `Err(reason)` names the first bad field.
    fn validate(&self) -> std::result::Result<(), String> {
        if self.obs_len != T_OBS {
            return Err(format!("obs_len is {}, expected {T_OBS}", self.obs_len));
        }
        if (self.dt - DT).abs() > 1e-9 {
            return Err(format!("dt is {}, expected {DT}", self.dt));
        }
        if self.activation != "relu" {
            return Err(format!(
                "activation {:?} is not supported (only \"relu\")",
                self.activation
            ));
        }
        if self.t_plan > MAX_HORIZON {
            return Err(format!(
                "t_plan is {}, expected 1..={MAX_HORIZON}",
                self.t_plan
            ));
        }
        let dims = [
            ("t_plan", self.t_plan),
            ("pred_len", self.pred_len),
            ("embedding_dim", self.embedding_dim),
            ("encoder_h_dim", self.encoder_h_dim),
            ("decoder_h_dim", self.decoder_h_dim),
            ("mlp_dim", self.mlp_dim),
            ("bottleneck_dim", self.bottleneck_dim),
            ("pool_hidden_dim", self.pool_hidden_dim),
        ];
        for (name, v) in dims {
            if v == 0 || v > MAX_DIM {
                return Err(format!("{name} is {v}, expected 1..={MAX_DIM}"));
            }
        }
        if self.noise_dim >= self.decoder_h_dim {
            return Err(format!(
                "noise_dim {} must be smaller than decoder_h_dim {}",
                self.noise_dim, self.decoder_h_dim
            ));
        }
        match self.kind {
            ModelKind::Teacher if self.pred_len != 1 => Err(format!(
                "a teacher predicts one step per call: pred_len is {}, expected 1",
                self.pred_len
            )),
            ModelKind::Student if self.pred_len != self.t_plan => Err(format!(
                "a student predicts the whole horizon: pred_len is {}, expected t_plan = {}",
                self.pred_len, self.t_plan
            )),
            _ => Ok(()),
        }
    }
}

/// The names and shapes (PyTorch `state_dict` order) of every tensor a generator with
/// config `cfg` holds; `W` shapes are `[out, in]`.
#[must_use]
pub fn expected_tensors(cfg: &ModelConfig) -> Vec<(String, Vec<usize>)> {
    Layout::new(cfg).tensors()
}

/// One tensor of a weights file: its PyTorch `state_dict` name and its shape (dimensions,
/// outermost first).
type Named = (String, Vec<usize>);

/// A PyTorch submodule of the generator, described by its `N` tensors: the one place that
/// names them and gives their shapes, for the loader's checks ([`expected_tensors`]) and for
/// reading the checked values that build the networks.
pub(crate) trait Module<const N: usize> {
    /// Name and shape of every tensor, in `state_dict` order.
    fn tensors(&self) -> [Named; N];

    /// The values of the tensors (f32, row-major), in [`Module::tensors`] order, from weights
    /// whose validation guaranteed them.
    fn values<'a>(&self, w: &'a ModelWeights) -> [&'a [f32]; N] {
        self.tensors().map(|(name, _)| w.get(&name))
    }
}

/// The tensors of `Linear(inp, out)` at `name`: `{name}.weight` `[out, inp]`, `{name}.bias`
/// `[out]`.
fn linear(name: &str, inp: usize, out: usize) -> [Named; 2] {
    [
        (format!("{name}.weight"), vec![out, inp]),
        (format!("{name}.bias"), vec![out]),
    ]
}

/// The tensors of the `nn.Sequential` mlp at `name`: `Linear(inp, mid)` (`.0`), ReLU,
/// `Linear(mid, out)` (`.2`), ReLU.
fn mlp(name: &str, inp: usize, mid: usize, out: usize) -> [Named; 4] {
    let [w1, b1] = linear(&format!("{name}.0"), inp, mid);
    let [w2, b2] = linear(&format!("{name}.2"), mid, out);
    [w1, b1, w2, b2]
}

/// `Linear(inp, out)` at `name` (the generator's `hidden2pos`): `weight [out, inp]`,
/// `bias [out]`.
#[derive(Debug, Clone)]
pub(crate) struct LinearModule {
    name: &'static str,
    /// Input size.
    pub(crate) inp: usize,
    /// Output size.
    pub(crate) out: usize,
}

impl Module<2> for LinearModule {
    fn tensors(&self) -> [Named; 2] {
        linear(self.name, self.inp, self.out)
    }
}

/// The two-layer `nn.Sequential` mlp at `prefix`: `Linear(inp, M)` (`.0`), ReLU,
/// `Linear(M, out)` (`.2`), ReLU. Tensors `w1 [M, inp]`, `b1 [M]`, `w2 [out, M]`,
/// `b2 [out]`.
#[derive(Debug, Clone)]
pub(crate) struct MlpModule {
    prefix: &'static str,
    /// Input size.
    pub(crate) inp: usize,
    mid: usize,
    out: usize,
}

impl Module<4> for MlpModule {
    fn tensors(&self) -> [Named; 4] {
        mlp(self.prefix, self.inp, self.mid, self.out)
    }
}

/// The spatial embedding `Linear(2, E)` at `{embed}.spatial_embedding` and the one-layer
/// `nn.LSTM` at `lstm` (input E, hidden H) it feeds: the encoder or the decoder. Tensors
/// `emb_w [E, 2]`, `emb_b [E]`, `w_ih [4H, E]`, `w_hh [4H, H]`, `b_ih [4H]`, `b_hh [4H]`
/// (gate order i, f, g, o).
#[derive(Debug, Clone)]
pub(crate) struct LstmModule {
    embed: &'static str,
    lstm: &'static str,
    e: usize,
    /// Hidden size H.
    pub(crate) h: usize,
}

impl Module<6> for LstmModule {
    fn tensors(&self) -> [Named; 6] {
        let (lstm, e, h) = (self.lstm, self.e, self.h);
        let [emb_w, emb_b] = linear(&format!("{}.spatial_embedding", self.embed), 2, e);
        [
            emb_w,
            emb_b,
            (format!("{lstm}.weight_ih_l0"), vec![4 * h, e]),
            (format!("{lstm}.weight_hh_l0"), vec![4 * h, h]),
            (format!("{lstm}.bias_ih_l0"), vec![4 * h]),
            (format!("{lstm}.bias_hh_l0"), vec![4 * h]),
        ]
    }
}

/// Social-GAN's `PoolHiddenNet` at `prefix`: the spatial embedding `Linear(2, E)`
/// (`spatial_embedding`) of the offsets between agents, concatenated with hidden states of
/// size H, then the mlp `mlp_pre_pool`: `Linear(E + H, P)`, ReLU, `Linear(P, B)`, ReLU.
/// Tensors `emb_w [E, 2]`, `emb_b [E]`, `w1 [P, E + H]`, `b1 [P]`, `w2 [B, P]`, `b2 [B]`.
#[derive(Debug, Clone)]
pub(crate) struct PoolModule {
    prefix: &'static str,
    e: usize,
    /// Size H of the pooled hidden states.
    pub(crate) h: usize,
    p: usize,
    b: usize,
}

impl Module<6> for PoolModule {
    fn tensors(&self) -> [Named; 6] {
        let (prefix, e) = (self.prefix, self.e);
        let [emb_w, emb_b] = linear(&format!("{prefix}.spatial_embedding"), 2, e);
        let [w1, b1, w2, b2] = mlp(
            &format!("{prefix}.mlp_pre_pool"),
            e + self.h,
            self.p,
            self.b,
        );
        [emb_w, emb_b, w1, b1, w2, b2]
    }
}

/// Name of the generator's noise parameter `[Z]`.
const FIXED_NOISE: &str = "fixed_noise";

/// The PyTorch modules of the Social-GAN generator for one [`ModelConfig`]: every tensor a
/// weights file holds, named and shaped once, for the loader's checks
/// ([`expected_tensors`]) and for building the networks from the checked values. Sizes as in
/// [`ModelConfig`]: E `embedding_dim`, He / Hd `encoder_h_dim` / `decoder_h_dim`, M
/// `mlp_dim`, B `bottleneck_dim`, P `pool_hidden_dim`, Z `noise_dim`.
#[derive(Debug, Clone)]
pub(crate) struct Layout {
    /// `encoder`: embedding `Linear(2, E)`, LSTM (E → He).
    pub(crate) enc: LstmModule,
    /// `pool_net`: pooling of the encoder states (H = He).
    pub(crate) pool: PoolModule,
    /// `mlp_decoder_context`: `[h_enc ; pooled]` (He + B) → M → Hd − Z.
    pub(crate) ctx: MlpModule,
    /// `decoder`: embedding `Linear(2, E)`, LSTM (E → Hd).
    pub(crate) dec: LstmModule,
    /// `decoder.hidden2pos`: `Linear(Hd, 2)`, the predicted displacement in metres.
    pub(crate) h2p: LinearModule,
    /// With `pool_every_timestep`: `decoder.pool_net` (H = Hd) and the refinement mlp
    /// `decoder.mlp` (`[h ; pooled]`, Hd + B → M → Hd).
    pub(crate) dec_pool: Option<(PoolModule, MlpModule)>,
    /// `fixed_noise` `[Z]`, when Z > 0.
    noise: Option<usize>,
}

impl Layout {
    /// The modules of a generator with config `cfg` (validated sizes).
    #[must_use]
    pub(crate) fn new(cfg: &ModelConfig) -> Self {
        let (e, he, hd) = (cfg.embedding_dim, cfg.encoder_h_dim, cfg.decoder_h_dim);
        let (m, b, p, z) = (
            cfg.mlp_dim,
            cfg.bottleneck_dim,
            cfg.pool_hidden_dim,
            cfg.noise_dim,
        );
        let lstm = |embed, lstm, h| LstmModule { embed, lstm, e, h };
        let pool = |prefix, h| PoolModule { prefix, e, h, p, b };
        let mlp = |prefix, inp, out| MlpModule {
            prefix,
            inp,
            mid: m,
            out,
        };
        Self {
            enc: lstm("encoder", "encoder.encoder", he),
            pool: pool("pool_net", he),
            ctx: mlp("mlp_decoder_context", he + b, hd - z),
            dec: lstm("decoder", "decoder.decoder", hd),
            h2p: LinearModule {
                name: "decoder.hidden2pos",
                inp: hd,
                out: 2,
            },
            dec_pool: cfg
                .pool_every_timestep
                .then(|| (pool("decoder.pool_net", hd), mlp("decoder.mlp", hd + b, hd))),
            noise: (z > 0).then_some(z),
        }
    }

    /// Every tensor's name and shape, in `state_dict` order.
    #[must_use]
    pub(crate) fn tensors(&self) -> Vec<Named> {
        let mut v = Vec::new();
        v.extend(self.enc.tensors());
        v.extend(self.pool.tensors());
        v.extend(self.ctx.tensors());
        v.extend(self.dec.tensors());
        v.extend(self.h2p.tensors());
        if let Some((pool, mlp)) = &self.dec_pool {
            v.extend(pool.tensors());
            v.extend(mlp.tensors());
        }
        if let Some(z) = self.noise {
            v.push((FIXED_NOISE.to_owned(), vec![z]));
        }
        v
    }

    /// The file's `fixed_noise` `[Z]` in validated weights (empty when Z = 0).
    pub(crate) fn fixed_noise<'a>(&self, w: &'a ModelWeights) -> &'a [f32] {
        if self.noise.is_some() {
            w.get(FIXED_NOISE)
        } else {
            &[]
        }
    }
}

/// One float32 tensor: `data` is row-major with `shape`.
#[derive(Debug, Clone, PartialEq)]
pub struct Tensor {
    /// Dimensions, outermost first.
    pub shape: Vec<usize>,
    /// Row-major values (`shape.iter().product()` of them).
    pub data: Vec<f32>,
}

/// A validated weights file: config plus every tensor the config calls for.
#[derive(Debug, Clone)]
pub struct ModelWeights {
    path: PathBuf,
    config: ModelConfig,
    trained: Option<bool>,
    tensors: BTreeMap<String, Tensor>,
}

/// Name used in errors for weights read from memory.
const MEMORY: &str = "<memory>";

impl ModelWeights {
    /// Reads and validates a `.safetensors` weights file.
    ///
    /// # Errors
    /// [`PredictorError::Io`] if the file cannot be read,
    /// [`PredictorError::NotRegularFile`] / [`PredictorError::FileTooLarge`] (checked before
    /// reading; see [`crate::file::read_bounded`]), otherwise as [`ModelWeights::from_bytes`]
    /// (with `path` in every error).
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = crate::file::read_bounded(path, crate::file::MAX_WEIGHTS_BYTES)?;
        Self::parse(&bytes, path.to_path_buf())
    }

    /// Validates an in-memory `.safetensors` image (errors name the file `<memory>`).
    ///
    /// # Errors
    /// [`PredictorError::NotSafetensors`], [`PredictorError::BadConfig`],
    /// [`PredictorError::UnknownModelKind`], [`PredictorError::MissingTensor`],
    /// [`PredictorError::WrongDtype`], [`PredictorError::ShapeMismatch`],
    /// [`PredictorError::NonFiniteWeight`], [`PredictorError::UnexpectedTensor`],
    /// [`PredictorError::MissingHash`], [`PredictorError::HashMismatch`]; see the module
    /// documentation for the order of the checks.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        Self::parse(bytes, PathBuf::from(MEMORY))
    }

    fn parse(bytes: &[u8], path: PathBuf) -> Result<Self> {
        let (st, meta) = read_header(bytes, &path)?;
        let trained = read_metadata_flags(&meta, &path)?;
        let raw = meta
            .get("config")
            .ok_or_else(|| bad_config(&path, "no \"config\" metadata entry".to_owned()))?;
        let config = parse_config(raw, &path)?;
        let tensors = read_tensors(&st, &config, &path)?;
        check_no_extra_tensor(&st, &tensors, &config, &path)?;
        check_content_hash(&meta, raw, &st, &path)?;
        Ok(Self {
            path,
            config,
            trained,
            tensors,
        })
    }

    /// The file the weights came from (`<memory>` for [`ModelWeights::from_bytes`]).
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The model configuration.
    #[must_use]
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// The `"trained"` metadata flag, if present.
    #[must_use]
    pub fn trained(&self) -> Option<bool> {
        self.trained
    }

    /// The tensor called `name` (PyTorch `state_dict` name), if the config calls for it.
    #[must_use]
    pub fn tensor(&self, name: &str) -> Option<&Tensor> {
        self.tensors.get(name)
    }

    /// Values of a tensor that validation guaranteed to exist.
    pub(crate) fn get(&self, name: &str) -> &[f32] {
        self.tensors
            .get(name)
            .map(|t| t.data.as_slice())
            .unwrap_or_else(|| panic!("validated weights lack tensor {name}"))
    }

    /// Checks the kind, for constructors of one specific network.
    pub(crate) fn expect_kind(&self, kind: ModelKind) -> Result<()> {
        if self.config.kind == kind {
            Ok(())
        } else {
            Err(PredictorError::WrongModelKind {
                path: self.path.clone(),
                expected: kind.as_str(),
                got: self.config.kind.as_str(),
            })
        }
    }
}

/// String metadata of a safetensors header (key → value).
type StringMetadata = HashMap<String, String>;

/// [`PredictorError::BadConfig`] for the file at `path`.
fn bad_config(path: &Path, reason: String) -> PredictorError {
    PredictorError::BadConfig {
        path: path.to_path_buf(),
        reason,
    }
}

/// Parses the safetensors image `bytes` and its string metadata (empty when the header has
/// none).
///
/// # Errors
/// [`PredictorError::NotSafetensors`].
fn read_header<'a>(bytes: &'a [u8], path: &Path) -> Result<(SafeTensors<'a>, StringMetadata)> {
    let not_safetensors = |e: safetensors::SafeTensorError| PredictorError::NotSafetensors {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    let st = SafeTensors::deserialize(bytes).map_err(not_safetensors)?;
    let (_, header) = SafeTensors::read_metadata(bytes).map_err(not_safetensors)?;
    Ok((st, header.metadata().clone().unwrap_or_default()))
}

/// Checks the optional `"format"` entry and reads the optional `"trained"` flag.
///
/// # Errors
/// [`PredictorError::BadConfig`] for a format other than [`WEIGHTS_FORMAT`] or a flag other
/// than `"true"` / `"false"`.
fn read_metadata_flags(meta: &StringMetadata, path: &Path) -> Result<Option<bool>> {
    if let Some(fmt) = meta.get("format")
        && fmt != WEIGHTS_FORMAT
    {
        return Err(bad_config(
            path,
            format!("metadata \"format\" is {fmt:?}, expected {WEIGHTS_FORMAT:?}"),
        ));
    }
    match meta.get("trained").map(String::as_str) {
        None => Ok(None),
        Some("true") => Ok(Some(true)),
        Some("false") => Ok(Some(false)),
        Some(other) => Err(bad_config(
            path,
            format!("metadata \"trained\" is {other:?}, expected \"true\" or \"false\""),
        )),
    }
}

/// Parses and validates the `"config"` metadata string `raw`: valid JSON, a known `kind`,
/// exactly the fields of [`ModelConfig`], sane values.
///
/// # Errors
/// [`PredictorError::BadConfig`], [`PredictorError::UnknownModelKind`].
fn parse_config(raw: &str, path: &Path) -> Result<ModelConfig> {
    let value: serde_json::Value = crate::json::parse(raw)
        .map_err(|e| bad_config(path, format!("config is not valid JSON: {e}")))?;
    match value.get("kind") {
        None => return Err(bad_config(path, "config has no \"kind\" field".to_owned())),
        Some(serde_json::Value::String(k)) if k == "teacher" || k == "student" => {}
        Some(serde_json::Value::String(k)) => {
            return Err(PredictorError::UnknownModelKind {
                path: path.to_path_buf(),
                kind: k.clone(),
            });
        }
        Some(other) => {
            return Err(PredictorError::UnknownModelKind {
                path: path.to_path_buf(),
                kind: other.to_string(),
            });
        }
    }
    let config: ModelConfig =
        serde_json::from_value(value).map_err(|e| bad_config(path, format!("config: {e}")))?;
    config
        .validate()
        .map_err(|reason| bad_config(path, reason))?;
    Ok(config)
}

/// Reads every tensor `config` calls for, in [`expected_tensors`] order, keyed by name.
///
/// # Errors
/// The first of [`PredictorError::MissingTensor`], [`PredictorError::WrongDtype`],
/// [`PredictorError::ShapeMismatch`], [`PredictorError::NonFiniteWeight`] found.
fn read_tensors(
    st: &SafeTensors<'_>,
    config: &ModelConfig,
    path: &Path,
) -> Result<BTreeMap<String, Tensor>> {
    let mut tensors = BTreeMap::new();
    for (name, shape) in expected_tensors(config) {
        let tensor = read_tensor(st, &name, shape, path)?;
        tensors.insert(name, tensor);
    }
    Ok(tensors)
}

/// Reads the float32 tensor `name`, which must have `shape` and finite values.
///
/// # Errors
/// [`PredictorError::MissingTensor`], [`PredictorError::WrongDtype`],
/// [`PredictorError::ShapeMismatch`], [`PredictorError::NonFiniteWeight`].
fn read_tensor(st: &SafeTensors<'_>, name: &str, shape: Vec<usize>, path: &Path) -> Result<Tensor> {
    let view = st.tensor(name).map_err(|_| PredictorError::MissingTensor {
        path: path.to_path_buf(),
        tensor: name.to_owned(),
    })?;
    if view.dtype() != Dtype::F32 {
        return Err(PredictorError::WrongDtype {
            path: path.to_path_buf(),
            tensor: name.to_owned(),
            got: format!("{:?}", view.dtype()),
        });
    }
    if view.shape() != shape.as_slice() {
        return Err(PredictorError::ShapeMismatch {
            path: path.to_path_buf(),
            tensor: name.to_owned(),
            expected: shape,
            got: view.shape().to_vec(),
        });
    }
    // The data may be unaligned: decode byte-wise, little endian.
    let data: Vec<f32> = view
        .data()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    if let Some(index) = data.iter().position(|v| !v.is_finite()) {
        return Err(PredictorError::NonFiniteWeight {
            path: path.to_path_buf(),
            tensor: name.to_owned(),
            index,
        });
    }
    Ok(Tensor { shape, data })
}

/// Checks that the file holds no tensor besides `tensors` (the first extra one in name order
/// is named).
///
/// # Errors
/// [`PredictorError::UnexpectedTensor`].
fn check_no_extra_tensor(
    st: &SafeTensors<'_>,
    tensors: &BTreeMap<String, Tensor>,
    config: &ModelConfig,
    path: &Path,
) -> Result<()> {
    let mut names = st.names();
    names.sort_unstable();
    if let Some(extra) = names.into_iter().find(|n| !tensors.contains_key(*n)) {
        return Err(PredictorError::UnexpectedTensor {
            path: path.to_path_buf(),
            tensor: extra.to_owned(),
            kind: config.kind.as_str().to_owned(),
        });
    }
    Ok(())
}

/// Checks the `"sha256"` metadata entry against [`content_sha256`] of the config string `raw`
/// and every tensor.
///
/// # Errors
/// [`PredictorError::MissingHash`], [`PredictorError::HashMismatch`].
fn check_content_hash(
    meta: &StringMetadata,
    raw: &str,
    st: &SafeTensors<'_>,
    path: &Path,
) -> Result<()> {
    let Some(expected) = meta.get("sha256") else {
        return Err(PredictorError::MissingHash {
            path: path.to_path_buf(),
        });
    };
    let found = content_sha256(
        raw,
        st.tensors()
            .iter()
            .map(|(n, v)| (n.as_str(), v.dtype(), v.shape(), v.data())),
    );
    if *expected != found {
        return Err(PredictorError::HashMismatch {
            path: path.to_path_buf(),
            expected: expected.clone(),
            found,
        });
    }
    Ok(())
}
