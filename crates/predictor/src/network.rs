//! What the teacher and the student share: the loaded network and its per-scene bookkeeping
//! ([`Net`]), the one loader of both ([`load`]), and their common public methods, written once
//! ([`network_api!`](crate::network::network_api)).
//!
//! Loading is the same for both kinds: the weights file is read bounded and checked tensor by
//! tensor ([`ModelWeights`]: names, shapes, dtypes, finiteness, content hash, errors naming the
//! file and the tensor), its kind must be the predictor's, the generator is built on the
//! instruction-set path [`simd_path`] chose, and the predictor must pass the load-time
//! self-check on the canonical scene ([`limits::self_check`]). Only the predictor around the
//! generator (its caches and the way it runs the generator) differs, given by [`Network`].

use crate::error::{PredictorError, Result};
use crate::generator::{Generator, Scratch};
use crate::history::check_finite;
use crate::simd::{Isa, SimdPath, simd_path};
use crate::weights::{ModelKind, ModelWeights};
use crate::{History, Predictor, T_OBS, check_batch, limits};

/// The loaded generator of a teacher or student and the state every such predictor keeps.
#[derive(Debug, Clone)]
pub(crate) struct Net {
    /// The repacked network and the instruction set it runs on.
    pub(crate) generator: Generator,
    /// The noise `z` appended to every agent's decoder state, `[noise_dim]` (standard-normal
    /// units; the file's `fixed_noise` until [`Net::set_noise`]).
    pub(crate) noise: Vec<f32>,
    /// Reusable buffers, grown to the scene size.
    pub(crate) s: Scratch,
    /// Agents of the current scene; 0 when there is none (or its cache went stale).
    pub(crate) n: usize,
    /// The scene's history `[n, T_OBS, 2]` (metres, the ego first).
    pub(crate) win0: Vec<f64>,
    /// The agents' last observed positions `[n, 2]` (metres).
    pub(crate) last: Vec<f64>,
}

impl Net {
    /// Starts a scene: stores its history and last positions and grows the scratch for its
    /// agents; the scene counts as set (`n`) only once the predictor has filled its caches.
    /// Returns the number of agents.
    pub(crate) fn start_scene(&mut self, history: &History) -> usize {
        let n = history.n_agents();
        self.n = 0;
        self.win0.clear();
        self.win0.extend_from_slice(history.positions());
        self.last.clear();
        for a in 0..n {
            self.last.extend_from_slice(&history.at(a, T_OBS - 1));
        }
        self.generator.reserve(&mut self.s, n);
        n
    }

    /// Sets the noise `z` (`[noise_dim]`) and clears the scene.
    ///
    /// # Errors
    /// [`PredictorError::InputShape`] if `z.len() != noise_dim`,
    /// [`PredictorError::NonFiniteInput`] on NaN/inf, [`PredictorError::InputOutOfRange`]
    /// for a component beyond [`limits::MAX_NOISE`].
    pub(crate) fn set_noise(&mut self, z: &[f64]) -> Result<()> {
        let zd = self.generator.cfg.noise_dim;
        if z.len() != zd {
            return Err(PredictorError::InputShape {
                what: "noise",
                shape: format!("[{zd}]"),
                expected: zd,
                got: z.len(),
            });
        }
        check_finite("noise", z)?;
        limits::check_noise(z)?;
        self.noise.clear();
        self.noise.extend(z.iter().map(|&v| v as f32));
        self.n = 0;
        Ok(())
    }

    /// Checks a [`Predictor::predict`] call of horizon `t` on the current scene. Returns the
    /// number of agents n and of candidates, or `None` when the scene holds the ego alone and
    /// there is nothing to predict.
    ///
    /// # Errors
    /// [`PredictorError::NoScene`] before a scene is set (or after it was cleared); otherwise
    /// as [`check_batch`].
    pub(crate) fn batch(
        &self,
        candidates: &[f64],
        out: &[f64],
        t: usize,
    ) -> Result<Option<(usize, usize)>> {
        let n = self.n;
        if n == 0 {
            return Err(PredictorError::NoScene);
        }
        let batch = check_batch(candidates, out, t, n, [self.last[0], self.last[1]])?;
        Ok((n > 1).then_some((n, batch)))
    }

    /// Runs the kernels on `path` from now on and clears the scene.
    ///
    /// # Errors
    /// [`PredictorError::SimdPath`] if this CPU lacks `path`.
    pub(crate) fn set_simd_path(&mut self, path: SimdPath) -> Result<()> {
        self.generator.set_isa(Isa::require(path)?);
        self.n = 0;
        Ok(())
    }
}

/// A predictor that runs a loaded generator: the teacher or the student.
pub(crate) trait Network: Predictor + Sized {
    /// The kind of weights it runs.
    const KIND: ModelKind;

    /// The predictor around `net`, with no scene.
    fn with_net(net: Net) -> Self;

    /// Its network and state.
    fn net_mut(&mut self) -> &mut Net;
}

/// Builds the predictor `N` from checked weights and runs the load-time self-check.
///
/// # Errors
/// [`PredictorError::WrongModelKind`] if the weights are of another kind than `N::KIND`;
/// [`PredictorError::SimdPath`] if `NUDGE_SIMD` names a path this CPU lacks;
/// [`PredictorError::SelfCheck`] (naming the weights' file) if the predictions on the
/// canonical scene are non-finite or implausible.
pub(crate) fn load<N: Network>(weights: &ModelWeights) -> Result<N> {
    weights.expect_kind(N::KIND)?;
    let generator = Generator::new(weights, Isa::require(simd_path()?)?);
    let noise = generator.fixed_noise.clone();
    let mut predictor = N::with_net(Net {
        generator,
        noise,
        s: Scratch::default(),
        n: 0,
        win0: Vec::new(),
        last: Vec::new(),
    });
    limits::self_check(&mut predictor, weights.path())?;
    predictor.net_mut().n = 0;
    Ok(predictor)
}

/// The public methods the teacher and the student share (loading, configuration, noise,
/// instruction-set path) and their [`Network`] implementation, for a type `$ty` named as its
/// [`ModelKind`] variant, that keeps its [`Net`] in the field `net` and its scene caches (any
/// type with an empty `Default`) in the field `scene`; `$kind` and `$other` name its kind and
/// the other one in the docs.
macro_rules! network_api {
    ($ty:ident, $kind:literal, $other:literal) => {
        impl $ty {
            #[doc = concat!("Loads a ", $kind, " from a `.safetensors` weights file.")]
            ///
            /// # Errors
            /// Any loading error of [`ModelWeights::from_file`](crate::ModelWeights::from_file)
            /// (file, config, tensor names, shapes, dtypes, finiteness, content hash; naming the
            /// file and the tensor);
            #[doc = concat!(
                "[`PredictorError::WrongModelKind`](crate::PredictorError::WrongModelKind) if the ",
                "file holds a ", $other, "; otherwise as [`", stringify!($ty), "::from_weights`]."
            )]
            pub fn from_file(path: impl AsRef<std::path::Path>) -> $crate::Result<Self> {
                Self::from_weights(&$crate::ModelWeights::from_file(path)?)
            }

            #[doc = concat!("Loads a ", $kind, " from an in-memory `.safetensors` image.")]
            ///
            /// # Errors
            #[doc = concat!("As [`", stringify!($ty), "::from_file`], without I/O errors.")]
            pub fn from_bytes(bytes: &[u8]) -> $crate::Result<Self> {
                Self::from_weights(&$crate::ModelWeights::from_bytes(bytes)?)
            }

            #[doc = concat!(
                "Builds a ", $kind, " from validated weights and runs the load-time self-check ",
                "([`limits::canonical_scene`](crate::limits::canonical_scene), with the file's noise)."
            )]
            ///
            /// # Errors
            #[doc = concat!(
                "[`PredictorError::WrongModelKind`](crate::PredictorError::WrongModelKind) if the ",
                "weights are a ", $other, "'s;"
            )]
            /// [`PredictorError::SelfCheck`](crate::PredictorError::SelfCheck) (naming the
            /// weights' file) if its predictions on the canonical scene are non-finite or
            /// implausible; [`PredictorError::SimdPath`](crate::PredictorError::SimdPath) if
            /// `NUDGE_SIMD` names a path this CPU lacks.
            pub fn from_weights(weights: &$crate::ModelWeights) -> $crate::Result<Self> {
                $crate::network::load(weights)
            }

            /// The network configuration.
            #[must_use]
            pub fn config(&self) -> &$crate::ModelConfig {
                &self.net.generator.cfg
            }

            /// Sets the noise vector `z` (`[noise_dim]`, standard-normal units; the file's
            /// `fixed_noise` until changed) used for every agent of every later scene. Clears
            /// the current scene (its cache used the old `z`).
            ///
            /// # Errors
            /// [`PredictorError::InputShape`](crate::PredictorError::InputShape) if
            /// `z.len() != noise_dim`,
            /// [`PredictorError::NonFiniteInput`](crate::PredictorError::NonFiniteInput) on
            /// NaN/inf,
            /// [`PredictorError::InputOutOfRange`](crate::PredictorError::InputOutOfRange) for a
            /// component beyond [`MAX_NOISE`](crate::limits::MAX_NOISE).
            pub fn set_noise(&mut self, z: &[f64]) -> $crate::Result<()> {
                self.net.set_noise(z)
            }

            /// The instruction-set path the kernels run on.
            #[must_use]
            pub fn simd_path(&self) -> $crate::SimdPath {
                self.net.generator.isa.path()
            }

            /// Runs the kernels on `path` from now on. Clears the current scene (its cache was
            /// computed on the old path; paths differ at the 1e-6 m level, see
            /// [`SimdPath`](crate::SimdPath)).
            ///
            /// # Errors
            /// [`PredictorError::SimdPath`](crate::PredictorError::SimdPath) if this CPU lacks
            /// `path`.
            pub fn set_simd_path(&mut self, path: $crate::SimdPath) -> $crate::Result<()> {
                self.net.set_simd_path(path)
            }
        }

        impl $crate::network::Network for $ty {
            const KIND: $crate::ModelKind = $crate::ModelKind::$ty;

            fn with_net(net: $crate::network::Net) -> Self {
                Self {
                    net,
                    scene: Default::default(),
                }
            }

            fn net_mut(&mut self) -> &mut $crate::network::Net {
                &mut self.net
            }
        }
    };
}

pub(crate) use network_api;
