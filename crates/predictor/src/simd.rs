//! Run-time choice of the vector instruction set the networks run on, and the crate's only
//! `unsafe` code.
//!
//! One build runs on every x86-64 CPU: the kernels (module `nn`) are written once,
//! generic over a `Simd` trait (16 f32 lanes with load, store, broadcast, multiply-add and max;
//! 8 f64 lanes for the dense layers' sums, which the one register tile reaches through the
//! precision trait `Elem`), and instantiated three times:
//!
//! | [`SimdPath`] | instructions | multiply-add |
//! |---|---|---|
//! | `portable` | the x86-64 baseline (SSE2), or whatever the build targets off x86-64 | `a * b + c`, two roundings |
//! | `avx2` | AVX2 + FMA (x86-64-v3), two 8-lane registers per vector | fused, one rounding |
//! | `avx512` | AVX-512F + AVX2 + FMA, one 16-lane register per vector | fused, one rounding |
//!
//! The dense layers (LSTM gates, mlps, pool agent terms, hidden2pos) accumulate in f64 on every
//! path (8-lane f64 vectors); the pooling's second layer, the `O(n²)` hot spot, and the
//! activations run in f32. The trained teacher's recursion amplifies f32 rounding: with
//! f32 accumulation everywhere its error against the f64 reference reached 1.2e-5 m on the
//! golden scenes; with f64 accumulation in the dense layers it stays near 5e-6 m.
//!
//! A model picks its path once, when it is loaded ([`simd_path`]: the environment variable
//! `NUDGE_SIMD=portable|avx2|avx512` if set, else the widest path the CPU supports), and can be
//! switched with `set_simd_path` on [`Teacher`](crate::Teacher) and [`Student`](crate::Student).
//!
//! # Numerics
//!
//! Every path sums each output's terms in the same order (input order, from the bias), so a
//! path is bit-reproducible run to run, for any batch size and any grouping of rows into
//! register tiles. `avx2` and `avx512` execute the same fused operations in the same order and
//! give identical bits; `portable` rounds each product separately and differs from them by
//! about 1e-6 m on predicted positions (all paths are within 1e-5 m of PyTorch; the tests check
//! every path the machine supports).
//!
//! Non-finite values propagate alike on every path: `max` and `min` return NaN when either
//! operand is NaN (`a` if `a` is, else `b`), so no ReLU (`max(x, 0)`), running maximum or clamp turns a NaN
//! into a finite number, and an overflowing network is reported by the checked predictor
//! whichever path it runs on (tested per kernel against an f64 reference).
//!
//! # Safety argument
//!
//! The instruction-set tokens `Avx2` and `Avx512` have a private field and are constructed
//! only by `Isa::new`, after `is_x86_feature_detected!` confirmed every feature their code
//! uses. Every `unsafe` block below either calls a `#[target_feature]` function or executes a
//! vector intrinsic while holding such a token (`self`), so the instructions exist on the
//! running CPU; the memory intrinsics read or write exactly the 16 `f32` of a `&[f32; 16]` /
//! `&mut [f32; 16]` (unaligned access), which the borrow makes valid.
#![allow(unsafe_code)]

use std::fmt;
use std::str::FromStr;
use std::sync::OnceLock;

use crate::error::{PredictorError, Result};

/// The instruction-set path of the network kernels (see the [module docs](self)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SimdPath {
    /// Baseline instructions, separate multiply and add; runs on every CPU.
    Portable,
    /// AVX2 with fused multiply-add (x86-64-v3).
    Avx2,
    /// AVX-512F with fused multiply-add.
    Avx512,
}

impl SimdPath {
    /// Every path, narrowest first.
    pub const ALL: [SimdPath; 3] = [SimdPath::Portable, SimdPath::Avx2, SimdPath::Avx512];

    /// The spelling used by `NUDGE_SIMD`, bench ids and reports: `portable`, `avx2`, `avx512`.
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            SimdPath::Portable => "portable",
            SimdPath::Avx2 => "avx2",
            SimdPath::Avx512 => "avx512",
        }
    }

    /// Whether the running CPU can execute this path.
    #[must_use]
    pub fn is_supported(self) -> bool {
        Isa::new(self).is_some()
    }

    /// Whether this path uses fused multiply-add (one rounding per multiply-add).
    #[must_use]
    pub fn is_fused(self) -> bool {
        !matches!(self, SimdPath::Portable)
    }
}

impl fmt::Display for SimdPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for SimdPath {
    type Err = PredictorError;

    /// Parses `portable`, `avx2` or `avx512` (exact spelling).
    fn from_str(s: &str) -> Result<Self> {
        SimdPath::ALL
            .into_iter()
            .find(|p| p.as_str() == s)
            .ok_or_else(|| PredictorError::SimdPath {
                requested: s.to_owned(),
                reason: "unknown path (expected portable, avx2 or avx512)",
            })
    }
}

/// The paths the running CPU supports, narrowest first (always starts with `Portable`).
#[must_use]
pub fn supported_simd_paths() -> Vec<SimdPath> {
    SimdPath::ALL
        .into_iter()
        .filter(|p| p.is_supported())
        .collect()
}

/// The widest path the running CPU supports.
#[must_use]
pub fn best_simd_path() -> SimdPath {
    supported_simd_paths().pop().unwrap_or(SimdPath::Portable)
}

/// Name of the environment variable that forces a path for newly loaded models.
pub const SIMD_ENV: &str = "NUDGE_SIMD";

/// The path newly loaded models take: `NUDGE_SIMD` when set (read once per process), else
/// [`best_simd_path`].
///
/// # Errors
/// [`PredictorError::SimdPath`] when `NUDGE_SIMD` names an unknown path or one this CPU lacks
/// (no silent fallback: a forced path that cannot run is an error).
pub fn simd_path() -> Result<SimdPath> {
    static CHOICE: OnceLock<std::result::Result<SimdPath, (String, &'static str)>> =
        OnceLock::new();
    CHOICE
        .get_or_init(|| {
            let env = std::env::var(SIMD_ENV).ok();
            path_from_env(env.as_deref()).map_err(split_error)
        })
        .clone()
        .map_err(|(requested, reason)| PredictorError::SimdPath { requested, reason })
}

fn split_error(e: PredictorError) -> (String, &'static str) {
    match e {
        PredictorError::SimdPath { requested, reason } => (requested, reason),
        other => (other.to_string(), "unexpected error"),
    }
}

/// The path for an optional `NUDGE_SIMD` value (`None` or empty: the best supported one).
///
/// # Errors
/// See [`simd_path`].
pub fn path_from_env(value: Option<&str>) -> Result<SimdPath> {
    match value.map(str::trim) {
        None | Some("") => Ok(best_simd_path()),
        Some(v) => {
            let path: SimdPath = v.parse()?;
            check_supported(path)?;
            Ok(path)
        }
    }
}

/// `Ok` when the running CPU supports `path`.
///
/// # Errors
/// [`PredictorError::SimdPath`] naming the path otherwise.
pub fn check_supported(path: SimdPath) -> Result<()> {
    if path.is_supported() {
        Ok(())
    } else {
        Err(PredictorError::SimdPath {
            requested: path.as_str().to_owned(),
            reason: "not supported by this CPU",
        })
    }
}

/// Multiply-add throughput probe: `iterations` rounds of independent 16-lane multiply-adds on
/// `path` (12 chains on `avx512`, 6 on `avx2`, 3 on `portable`: enough to hide the latency),
/// registers only, one thread. Returns the multiply-adds done and a checksum that keeps the
/// work observable. Time it to get the path's peak rate (the inference bench does).
///
/// # Errors
/// [`PredictorError::SimdPath`] if this CPU lacks `path`.
pub fn fma_peak_loop(path: SimdPath, iterations: u64) -> Result<(u64, f32)> {
    let isa = Isa::require(path)?;
    Ok(isa.run(crate::nn::PeakLoop {
        iterations,
        a: std::hint::black_box(0.999),
    }))
}

// ---------------------------------------------------------------------------------------------
// The vector abstraction.
// ---------------------------------------------------------------------------------------------

/// Width of every f32 vector of [`Simd`], in lanes.
pub(crate) const LANES: usize = 16;
/// Width of every f64 vector of [`Simd`], in lanes.
pub(crate) const LANES_D: usize = 8;

/// 16 f32 lanes on one instruction set. Implemented by the tokens [`Portable`], [`Avx2`],
/// [`Avx512`]; generic kernels call these methods and nothing else path-specific.
pub(crate) trait Simd: Copy {
    /// 16 lanes.
    type V: Copy;
    /// The path this token runs.
    const PATH: SimdPath;
    /// Rows per register tile of the matrix kernels (see `nn`).
    const TILE_ROWS: usize;
    /// 16-lane output blocks per register tile (1 or 2).
    const TILE_BLOCKS: usize;
    /// Rows per register tile of the fused LSTM cell (four gate blocks per row, see `nn`).
    const LSTM_ROWS: usize;

    /// Every lane `x`.
    fn splat(self, x: f32) -> Self::V;
    /// The 16 values of `x`.
    fn load(self, x: &[f32; LANES]) -> Self::V;
    /// Writes the 16 lanes to `y`.
    fn store(self, v: Self::V, y: &mut [f32; LANES]);
    /// `a * b + c` per lane: fused on the FMA paths, two roundings on the portable one.
    fn mul_add(self, a: Self::V, b: Self::V, c: Self::V) -> Self::V;
    /// Per lane [`max_nan`]: the larger operand, NaN when either is NaN (`a` when `a` is
    /// NaN, else `b`), the same bits on every path.
    fn max(self, a: Self::V, b: Self::V) -> Self::V;
    /// Scalar `a * b + c` with the same rounding as [`Simd::mul_add`] (for the
    /// auto-vectorised element-wise loops: activations).
    fn fma1(self, a: f32, b: f32, c: f32) -> f32;
    /// Per lane [`min_nan`]: the smaller operand, NaN when either is NaN (`a` when `a` is
    /// NaN, else `b`), the same bits on every path.
    fn min(self, a: Self::V, b: Self::V) -> Self::V;
    /// `a + b` per lane (IEEE, one rounding).
    fn add(self, a: Self::V, b: Self::V) -> Self::V;
    /// `a - b` per lane (IEEE, one rounding).
    fn sub(self, a: Self::V, b: Self::V) -> Self::V;
    /// `a * b` per lane (IEEE, one rounding).
    fn mul(self, a: Self::V, b: Self::V) -> Self::V;
    /// `a / b` per lane (IEEE, correctly rounded).
    fn div(self, a: Self::V, b: Self::V) -> Self::V;
    /// Per lane, the bit pattern of `a` shifted left by 23 bits (`f32::from_bits(a.to_bits()
    /// << 23)`: moves an integer held in the low mantissa bits into the exponent field).
    fn shl23(self, a: Self::V) -> Self::V;

    /// 8 f64 lanes (the dense layers' accumulators).
    type D: Copy;
    /// Every lane `x`.
    fn splat_d(self, x: f64) -> Self::D;
    /// The 8 values of `x`.
    fn load_d(self, x: &[f64; LANES_D]) -> Self::D;
    /// `a * b + c` per lane, rounded as [`Simd::mul_add`].
    fn mul_add_d(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D;
    /// The 8 lanes rounded to f32 (to nearest), written to `y`.
    fn store_d_f32(self, v: Self::D, y: &mut [f32; LANES_D]);
}

/// A precision the matrix kernels of `nn` sum in: `f32`, 16 lanes a vector ([`Simd::V`]), or
/// `f64`, 8 lanes a vector ([`Simd::D`]). The kernels' inputs and outputs are f32 either way: an
/// input is widened exactly ([`Elem::splat`]) and an output is rounded to f32 once
/// ([`Elem::store_f32`]). The register tile is written once over this trait; every method is
/// one [`Simd`] operation of the precision (inlined), so each instantiation is the code a
/// hand-written copy for that precision would be, with the same operations in the same order.
pub(crate) trait Elem: Copy + Default + fmt::Debug + 'static {
    /// Lanes of one vector and of one packed weight block: 16 for f32, 8 for f64.
    const LANES: usize;
    /// One packed block, `[Self; LANES]`.
    type Block: Copy + Default + fmt::Debug + AsMut<[Self]>;
    /// [`Elem::LANES`] values in registers of the instruction set `S`.
    type V<S: Simd>: Copy;
    /// `x` in this precision (exact).
    fn widen(x: f32) -> Self;
    /// Every lane `x`, widened exactly.
    fn splat<S: Simd>(s: S, x: f32) -> Self::V<S>;
    /// The values of `x`.
    fn load<S: Simd>(s: S, x: &Self::Block) -> Self::V<S>;
    /// `a * b + c` per lane: fused on the FMA paths, two roundings on the portable one (as
    /// [`Simd::mul_add`]).
    fn mul_add<S: Simd>(s: S, a: Self::V<S>, b: Self::V<S>, c: Self::V<S>) -> Self::V<S>;
    /// Writes the first `y.len()` lanes (at most [`Elem::LANES`]) of `v` to `y`, rounded to
    /// f32 (to nearest; nothing to round for f32) and, when `relu`, passed through
    /// `max_nan(x, 0)` (rounding is monotonic: ReLU before or after it gives the same bits).
    fn store_f32<S: Simd>(s: S, v: Self::V<S>, relu: bool, y: &mut [f32]);
}

impl Elem for f32 {
    const LANES: usize = LANES;
    type Block = [f32; LANES];
    type V<S: Simd> = S::V;

    #[inline(always)]
    fn widen(x: f32) -> Self {
        x
    }
    #[inline(always)]
    fn splat<S: Simd>(s: S, x: f32) -> S::V {
        s.splat(x)
    }
    #[inline(always)]
    fn load<S: Simd>(s: S, x: &Self::Block) -> S::V {
        s.load(x)
    }
    #[inline(always)]
    fn mul_add<S: Simd>(s: S, a: S::V, b: S::V, c: S::V) -> S::V {
        s.mul_add(a, b, c)
    }
    #[inline(always)]
    fn store_f32<S: Simd>(s: S, v: S::V, relu: bool, y: &mut [f32]) {
        let v = if relu { s.max(v, s.splat(0.0)) } else { v };
        if let Ok(full) = <&mut [f32; LANES]>::try_from(&mut *y) {
            s.store(v, full);
        } else {
            let mut t = [0.0f32; LANES];
            s.store(v, &mut t);
            let n = y.len();
            y.copy_from_slice(&t[..n]);
        }
    }
}

impl Elem for f64 {
    const LANES: usize = LANES_D;
    type Block = [f64; LANES_D];
    type V<S: Simd> = S::D;

    #[inline(always)]
    fn widen(x: f32) -> Self {
        f64::from(x)
    }
    #[inline(always)]
    fn splat<S: Simd>(s: S, x: f32) -> S::D {
        s.splat_d(f64::from(x))
    }
    #[inline(always)]
    fn load<S: Simd>(s: S, x: &Self::Block) -> S::D {
        s.load_d(x)
    }
    #[inline(always)]
    fn mul_add<S: Simd>(s: S, a: S::D, b: S::D, c: S::D) -> S::D {
        s.mul_add_d(a, b, c)
    }
    #[inline(always)]
    fn store_f32<S: Simd>(s: S, v: S::D, relu: bool, y: &mut [f32]) {
        let mut t = [0.0f32; LANES_D];
        s.store_d_f32(v, &mut t);
        if relu {
            t = t.map(|x| max_nan(x, 0.0));
        }
        let n = y.len();
        y.copy_from_slice(&t[..n]);
    }
}

/// `max(a, b)` that propagates NaN: `a` when `a > b` or `a` is NaN, else `b` (so `b` when `b`
/// is NaN). Unlike [`f32::max`], which returns the other operand, and the bare x86 `max`
/// instruction (`if a > b { a } else { b }`), which drops a NaN in `a`, a non-finite value can
/// never turn into a finite one here: the kernels' ReLUs (`max(x, 0)`) and running maxima
/// (`max(acc, x)`) keep a NaN wherever it enters. For ordered operands the result is the bare
/// x86 rule's (`max(-0.0, 0.0)` is `0.0`, `max(0.0, -0.0)` is `-0.0`).
#[inline(always)]
#[must_use]
pub(crate) fn max_nan(a: f32, b: f32) -> f32 {
    if a > b || a.is_nan() { a } else { b }
}

/// `min(a, b)` that propagates NaN: `a` when `a < b` or `a` is NaN, else `b` (see
/// [`max_nan`]).
#[inline(always)]
#[must_use]
pub(crate) fn min_nan(a: f32, b: f32) -> f32 {
    if a < b || a.is_nan() { a } else { b }
}

/// A computation generic over the instruction set, run by [`Isa::run`] with the target
/// features of the chosen path enabled. Implementations mark `run` `#[inline(always)]` so that
/// all of it is compiled for that path.
pub(crate) trait Kernel {
    /// What the kernel returns.
    type Out;
    /// Runs the kernel on instruction set `s`.
    fn run<S: Simd>(self, s: S) -> Self::Out;
}

/// Token of the portable path (always available).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Portable;

impl Simd for Portable {
    type V = [f32; LANES];
    const PATH: SimdPath = SimdPath::Portable;
    const TILE_ROWS: usize = 2;
    const TILE_BLOCKS: usize = 1;
    const LSTM_ROWS: usize = 1;

    #[inline(always)]
    fn splat(self, x: f32) -> Self::V {
        [x; LANES]
    }
    #[inline(always)]
    fn load(self, x: &[f32; LANES]) -> Self::V {
        *x
    }
    #[inline(always)]
    fn store(self, v: Self::V, y: &mut [f32; LANES]) {
        *y = v;
    }
    #[inline(always)]
    fn mul_add(self, a: Self::V, b: Self::V, mut c: Self::V) -> Self::V {
        for l in 0..LANES {
            c[l] += a[l] * b[l];
        }
        c
    }
    #[inline(always)]
    fn max(self, mut a: Self::V, b: Self::V) -> Self::V {
        for l in 0..LANES {
            a[l] = max_nan(a[l], b[l]);
        }
        a
    }
    #[inline(always)]
    fn fma1(self, a: f32, b: f32, c: f32) -> f32 {
        a * b + c
    }
    #[inline(always)]
    fn min(self, mut a: Self::V, b: Self::V) -> Self::V {
        for l in 0..LANES {
            a[l] = min_nan(a[l], b[l]);
        }
        a
    }
    #[inline(always)]
    fn add(self, mut a: Self::V, b: Self::V) -> Self::V {
        for l in 0..LANES {
            a[l] += b[l];
        }
        a
    }
    #[inline(always)]
    fn sub(self, mut a: Self::V, b: Self::V) -> Self::V {
        for l in 0..LANES {
            a[l] -= b[l];
        }
        a
    }
    #[inline(always)]
    fn mul(self, mut a: Self::V, b: Self::V) -> Self::V {
        for l in 0..LANES {
            a[l] *= b[l];
        }
        a
    }
    #[inline(always)]
    fn div(self, mut a: Self::V, b: Self::V) -> Self::V {
        for l in 0..LANES {
            a[l] /= b[l];
        }
        a
    }
    #[inline(always)]
    fn shl23(self, a: Self::V) -> Self::V {
        a.map(|v| f32::from_bits(v.to_bits() << 23))
    }

    type D = [f64; LANES_D];
    #[inline(always)]
    fn splat_d(self, x: f64) -> Self::D {
        [x; LANES_D]
    }
    #[inline(always)]
    fn load_d(self, x: &[f64; LANES_D]) -> Self::D {
        *x
    }
    #[inline(always)]
    fn mul_add_d(self, a: Self::D, b: Self::D, mut c: Self::D) -> Self::D {
        for l in 0..LANES_D {
            c[l] += a[l] * b[l];
        }
        c
    }
    #[inline(always)]
    fn store_d_f32(self, v: Self::D, y: &mut [f32; LANES_D]) {
        *y = v.map(|x| x as f32);
    }
}

#[cfg(target_arch = "x86_64")]
pub(crate) use x86::{Avx2, Avx512};

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::{
        __m256, __m256d, __m512, __m512d, _CMP_UNORD_Q, _mm_storeu_ps, _mm256_add_ps,
        _mm256_blendv_ps, _mm256_castps_si256, _mm256_castsi256_ps, _mm256_cmp_ps, _mm256_cvtpd_ps,
        _mm256_div_ps, _mm256_fmadd_pd, _mm256_fmadd_ps, _mm256_loadu_pd, _mm256_loadu_ps,
        _mm256_max_ps, _mm256_min_ps, _mm256_mul_ps, _mm256_set1_pd, _mm256_set1_ps,
        _mm256_slli_epi32, _mm256_storeu_ps, _mm256_sub_ps, _mm512_add_ps, _mm512_castps_si512,
        _mm512_castsi512_ps, _mm512_cmp_ps_mask, _mm512_cvtpd_ps, _mm512_div_ps, _mm512_fmadd_pd,
        _mm512_fmadd_ps, _mm512_loadu_pd, _mm512_loadu_ps, _mm512_mask_mov_ps, _mm512_max_ps,
        _mm512_min_ps, _mm512_mul_ps, _mm512_set1_pd, _mm512_set1_ps, _mm512_slli_epi32,
        _mm512_storeu_ps, _mm512_sub_ps,
    };

    use super::{LANES, LANES_D, Simd, SimdPath};

    /// Token of the AVX2 + FMA path; exists only where the CPU has both (see the module's
    /// safety argument).
    #[derive(Debug, Clone, Copy)]
    pub(crate) struct Avx2 {
        _detected: (),
    }

    /// Token of the AVX-512F + AVX2 + FMA path; exists only where the CPU has all three.
    #[derive(Debug, Clone, Copy)]
    pub(crate) struct Avx512 {
        _detected: (),
    }

    impl Avx2 {
        pub(super) fn detect() -> Option<Self> {
            (is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"))
                .then_some(Self { _detected: () })
        }
    }

    impl Avx512 {
        pub(super) fn detect() -> Option<Self> {
            (Avx2::detect().is_some() && is_x86_feature_detected!("avx512f"))
                .then_some(Self { _detected: () })
        }
    }

    impl Simd for Avx2 {
        type V = [__m256; 2];
        const PATH: SimdPath = SimdPath::Avx2;
        const TILE_ROWS: usize = 4;
        const TILE_BLOCKS: usize = 1;
        const LSTM_ROWS: usize = 1;

        #[inline(always)]
        fn splat(self, x: f32) -> Self::V {
            // SAFETY: AVX is available (token); no memory access.
            let v = unsafe { _mm256_set1_ps(x) };
            [v, v]
        }
        #[inline(always)]
        fn load(self, x: &[f32; LANES]) -> Self::V {
            let p = x.as_ptr();
            // SAFETY: AVX is available (token); `p..p+16` is the borrowed array.
            unsafe { [_mm256_loadu_ps(p), _mm256_loadu_ps(p.add(8))] }
        }
        #[inline(always)]
        fn store(self, v: Self::V, y: &mut [f32; LANES]) {
            let p = y.as_mut_ptr();
            // SAFETY: AVX is available (token); `p..p+16` is the mutably borrowed array.
            unsafe {
                _mm256_storeu_ps(p, v[0]);
                _mm256_storeu_ps(p.add(8), v[1]);
            }
        }
        #[inline(always)]
        fn mul_add(self, a: Self::V, b: Self::V, c: Self::V) -> Self::V {
            // SAFETY: FMA is available (token); no memory access.
            unsafe {
                [
                    _mm256_fmadd_ps(a[0], b[0], c[0]),
                    _mm256_fmadd_ps(a[1], b[1], c[1]),
                ]
            }
        }
        #[inline(always)]
        fn max(self, a: Self::V, b: Self::V) -> Self::V {
            // `maxps` gives `b` when either lane is NaN; lanes where `a` is NaN take `a`.
            // SAFETY: AVX is available (token); no memory access.
            unsafe {
                let one = |a, b| {
                    let nan = _mm256_cmp_ps::<_CMP_UNORD_Q>(a, a);
                    _mm256_blendv_ps(_mm256_max_ps(a, b), a, nan)
                };
                [one(a[0], b[0]), one(a[1], b[1])]
            }
        }
        #[inline(always)]
        fn fma1(self, a: f32, b: f32, c: f32) -> f32 {
            a.mul_add(b, c)
        }
        #[inline(always)]
        fn min(self, a: Self::V, b: Self::V) -> Self::V {
            // As `max`: `minps`, then `a` where `a` is NaN.
            // SAFETY: AVX is available (token); no memory access.
            unsafe {
                let one = |a, b| {
                    let nan = _mm256_cmp_ps::<_CMP_UNORD_Q>(a, a);
                    _mm256_blendv_ps(_mm256_min_ps(a, b), a, nan)
                };
                [one(a[0], b[0]), one(a[1], b[1])]
            }
        }
        #[inline(always)]
        fn add(self, a: Self::V, b: Self::V) -> Self::V {
            // SAFETY: AVX is available (token); no memory access.
            unsafe { [_mm256_add_ps(a[0], b[0]), _mm256_add_ps(a[1], b[1])] }
        }
        #[inline(always)]
        fn sub(self, a: Self::V, b: Self::V) -> Self::V {
            // SAFETY: AVX is available (token); no memory access.
            unsafe { [_mm256_sub_ps(a[0], b[0]), _mm256_sub_ps(a[1], b[1])] }
        }
        #[inline(always)]
        fn mul(self, a: Self::V, b: Self::V) -> Self::V {
            // SAFETY: AVX is available (token); no memory access.
            unsafe { [_mm256_mul_ps(a[0], b[0]), _mm256_mul_ps(a[1], b[1])] }
        }
        #[inline(always)]
        fn div(self, a: Self::V, b: Self::V) -> Self::V {
            // SAFETY: AVX is available (token); no memory access.
            unsafe { [_mm256_div_ps(a[0], b[0]), _mm256_div_ps(a[1], b[1])] }
        }
        #[inline(always)]
        fn shl23(self, a: Self::V) -> Self::V {
            // SAFETY: AVX2 is available (token); no memory access (bit casts and a shift).
            unsafe {
                a.map(|v| _mm256_castsi256_ps(_mm256_slli_epi32::<23>(_mm256_castps_si256(v))))
            }
        }

        type D = [__m256d; 2];
        #[inline(always)]
        fn splat_d(self, x: f64) -> Self::D {
            // SAFETY: AVX is available (token); no memory access.
            let v = unsafe { _mm256_set1_pd(x) };
            [v, v]
        }
        #[inline(always)]
        fn load_d(self, x: &[f64; LANES_D]) -> Self::D {
            let p = x.as_ptr();
            // SAFETY: AVX is available (token); `p..p+8` is the borrowed array.
            unsafe { [_mm256_loadu_pd(p), _mm256_loadu_pd(p.add(4))] }
        }
        #[inline(always)]
        fn mul_add_d(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D {
            // SAFETY: FMA is available (token); no memory access.
            unsafe {
                [
                    _mm256_fmadd_pd(a[0], b[0], c[0]),
                    _mm256_fmadd_pd(a[1], b[1], c[1]),
                ]
            }
        }
        #[inline(always)]
        fn store_d_f32(self, v: Self::D, y: &mut [f32; LANES_D]) {
            let p = y.as_mut_ptr();
            // SAFETY: AVX is available (token); `p..p+8` is the mutably borrowed array.
            unsafe {
                _mm_storeu_ps(p, _mm256_cvtpd_ps(v[0]));
                _mm_storeu_ps(p.add(4), _mm256_cvtpd_ps(v[1]));
            }
        }
    }

    impl Simd for Avx512 {
        type V = __m512;
        const PATH: SimdPath = SimdPath::Avx512;
        const TILE_ROWS: usize = 8;
        const TILE_BLOCKS: usize = 2;
        const LSTM_ROWS: usize = 4;

        #[inline(always)]
        fn splat(self, x: f32) -> Self::V {
            // SAFETY: AVX-512F is available (token); no memory access.
            unsafe { _mm512_set1_ps(x) }
        }
        #[inline(always)]
        fn load(self, x: &[f32; LANES]) -> Self::V {
            // SAFETY: AVX-512F is available (token); the 16 values are the borrowed array.
            unsafe { _mm512_loadu_ps(x.as_ptr()) }
        }
        #[inline(always)]
        fn store(self, v: Self::V, y: &mut [f32; LANES]) {
            // SAFETY: AVX-512F is available (token); the 16 values are the borrowed array.
            unsafe { _mm512_storeu_ps(y.as_mut_ptr(), v) }
        }
        #[inline(always)]
        fn mul_add(self, a: Self::V, b: Self::V, c: Self::V) -> Self::V {
            // SAFETY: AVX-512F is available (token); no memory access.
            unsafe { _mm512_fmadd_ps(a, b, c) }
        }
        #[inline(always)]
        fn max(self, a: Self::V, b: Self::V) -> Self::V {
            // `vmaxps` gives `b` when either lane is NaN; lanes where `a` is NaN take `a`.
            // SAFETY: AVX-512F is available (token); no memory access.
            unsafe {
                let nan = _mm512_cmp_ps_mask::<_CMP_UNORD_Q>(a, a);
                _mm512_mask_mov_ps(_mm512_max_ps(a, b), nan, a)
            }
        }
        #[inline(always)]
        fn fma1(self, a: f32, b: f32, c: f32) -> f32 {
            a.mul_add(b, c)
        }
        #[inline(always)]
        fn min(self, a: Self::V, b: Self::V) -> Self::V {
            // As `max`: `vminps`, then `a` where `a` is NaN.
            // SAFETY: AVX-512F is available (token); no memory access.
            unsafe {
                let nan = _mm512_cmp_ps_mask::<_CMP_UNORD_Q>(a, a);
                _mm512_mask_mov_ps(_mm512_min_ps(a, b), nan, a)
            }
        }
        #[inline(always)]
        fn add(self, a: Self::V, b: Self::V) -> Self::V {
            // SAFETY: AVX-512F is available (token); no memory access.
            unsafe { _mm512_add_ps(a, b) }
        }
        #[inline(always)]
        fn sub(self, a: Self::V, b: Self::V) -> Self::V {
            // SAFETY: AVX-512F is available (token); no memory access.
            unsafe { _mm512_sub_ps(a, b) }
        }
        #[inline(always)]
        fn mul(self, a: Self::V, b: Self::V) -> Self::V {
            // SAFETY: AVX-512F is available (token); no memory access.
            unsafe { _mm512_mul_ps(a, b) }
        }
        #[inline(always)]
        fn div(self, a: Self::V, b: Self::V) -> Self::V {
            // SAFETY: AVX-512F is available (token); no memory access.
            unsafe { _mm512_div_ps(a, b) }
        }
        #[inline(always)]
        fn shl23(self, a: Self::V) -> Self::V {
            // SAFETY: AVX-512F is available (token); no memory access (bit casts and a shift).
            unsafe { _mm512_castsi512_ps(_mm512_slli_epi32::<23>(_mm512_castps_si512(a))) }
        }

        type D = __m512d;
        #[inline(always)]
        fn splat_d(self, x: f64) -> Self::D {
            // SAFETY: AVX-512F is available (token); no memory access.
            unsafe { _mm512_set1_pd(x) }
        }
        #[inline(always)]
        fn load_d(self, x: &[f64; LANES_D]) -> Self::D {
            // SAFETY: AVX-512F is available (token); the 8 values are the borrowed array.
            unsafe { _mm512_loadu_pd(x.as_ptr()) }
        }
        #[inline(always)]
        fn mul_add_d(self, a: Self::D, b: Self::D, c: Self::D) -> Self::D {
            // SAFETY: AVX-512F is available (token); no memory access.
            unsafe { _mm512_fmadd_pd(a, b, c) }
        }
        #[inline(always)]
        fn store_d_f32(self, v: Self::D, y: &mut [f32; LANES_D]) {
            // SAFETY: AVX-512F (and AVX) are available (token); the 8 values are the borrowed
            // array.
            unsafe { _mm256_storeu_ps(y.as_mut_ptr(), _mm512_cvtpd_ps(v)) }
        }
    }

    /// Runs `k` compiled for AVX2 + FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn run_avx2<K: super::Kernel>(s: Avx2, k: K) -> K::Out {
        k.run(s)
    }

    /// Runs `k` compiled for AVX-512F + AVX2 + FMA.
    #[target_feature(enable = "avx512f,avx2,fma")]
    pub(super) fn run_avx512<K: super::Kernel>(s: Avx512, k: K) -> K::Out {
        k.run(s)
    }
}

/// A detected instruction set: the token that lets kernels run on it.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Isa {
    /// Baseline.
    Portable(Portable),
    /// AVX2 + FMA.
    #[cfg(target_arch = "x86_64")]
    Avx2(Avx2),
    /// AVX-512F + AVX2 + FMA.
    #[cfg(target_arch = "x86_64")]
    Avx512(Avx512),
}

impl Isa {
    /// The token of `path`, or `None` when the CPU lacks it.
    pub(crate) fn new(path: SimdPath) -> Option<Self> {
        match path {
            SimdPath::Portable => Some(Isa::Portable(Portable)),
            #[cfg(target_arch = "x86_64")]
            SimdPath::Avx2 => Avx2::detect().map(Isa::Avx2),
            #[cfg(target_arch = "x86_64")]
            SimdPath::Avx512 => Avx512::detect().map(Isa::Avx512),
            #[cfg(not(target_arch = "x86_64"))]
            _ => None,
        }
    }

    /// The token of `path`.
    ///
    /// # Errors
    /// [`PredictorError::SimdPath`] when the CPU lacks it.
    pub(crate) fn require(path: SimdPath) -> Result<Self> {
        Self::new(path).ok_or_else(|| PredictorError::SimdPath {
            requested: path.as_str().to_owned(),
            reason: "not supported by this CPU",
        })
    }

    /// The path of this token.
    pub(crate) fn path(self) -> SimdPath {
        match self {
            Isa::Portable(_) => SimdPath::Portable,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2(_) => SimdPath::Avx2,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512(_) => SimdPath::Avx512,
        }
    }

    /// Runs `k` on this instruction set.
    #[inline]
    pub(crate) fn run<K: Kernel>(self, k: K) -> K::Out {
        match self {
            Isa::Portable(s) => k.run(s),
            // SAFETY: an `Avx2` token exists only where AVX2 and FMA were detected.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2(s) => unsafe { x86::run_avx2(s, k) },
            // SAFETY: an `Avx512` token exists only where AVX-512F, AVX2 and FMA were detected.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512(s) => unsafe { x86::run_avx512(s, k) },
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for p in SimdPath::ALL {
            assert_eq!(p.as_str().parse::<SimdPath>().unwrap(), p);
            assert_eq!(p.to_string(), p.as_str());
        }
        assert!(matches!(
            "AVX2".parse::<SimdPath>(),
            Err(PredictorError::SimdPath { .. })
        ));
    }

    #[test]
    fn env_value_selects_or_rejects() {
        assert_eq!(path_from_env(None).unwrap(), best_simd_path());
        assert_eq!(path_from_env(Some("")).unwrap(), best_simd_path());
        assert_eq!(path_from_env(Some("portable")).unwrap(), SimdPath::Portable);
        let err = path_from_env(Some("sse9")).unwrap_err().to_string();
        assert!(err.contains("sse9"), "{err}");
        for p in SimdPath::ALL {
            assert_eq!(path_from_env(Some(p.as_str())).is_ok(), p.is_supported());
        }
    }

    #[test]
    fn supported_paths_are_ordered_and_start_portable() {
        let s = supported_simd_paths();
        assert_eq!(s[0], SimdPath::Portable);
        assert!(s.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(*s.last().unwrap(), best_simd_path());
        // AVX-512 implies AVX2 here.
        if SimdPath::Avx512.is_supported() {
            assert!(SimdPath::Avx2.is_supported());
        }
    }
}
