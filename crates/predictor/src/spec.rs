//! What to predict with, named once: [`PredictorKind`] (the vocabulary `teacher`, `student`,
//! `constant_velocity`), the one resolver of the shipped models' paths ([`model_path`]), and
//! [`PredictorSpec`], a predictor whose weights are parsed once and cloned for every run.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::{PredictorError, Result};
use crate::weights::{ModelKind, ModelWeights};
use crate::{ConstantVelocity, Predictor, Student, Teacher, check_horizon};

/// Environment variable naming the assets directory (`<assets>/models/*.safetensors`).
pub const ASSETS_ENV: &str = "NUDGE_ASSETS";

/// The kinds of predictor, named as everywhere in nudge (Rust, CLI, Python, records).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PredictorKind {
    /// The Social-GAN teacher.
    Teacher,
    /// The distilled student.
    Student,
    /// The interaction-unaware constant-velocity baseline.
    ConstantVelocity,
}

impl PredictorKind {
    /// Every kind.
    pub const ALL: [Self; 3] = [Self::Teacher, Self::Student, Self::ConstantVelocity];

    /// `"teacher"`, `"student"` or `"constant_velocity"`.
    #[must_use]
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Teacher => "teacher",
            Self::Student => "student",
            Self::ConstantVelocity => "constant_velocity",
        }
    }

    /// The network kind of a learned predictor (`None` for constant velocity).
    #[must_use]
    pub fn model(self) -> Option<ModelKind> {
        match self {
            Self::Teacher => Some(ModelKind::Teacher),
            Self::Student => Some(ModelKind::Student),
            Self::ConstantVelocity => None,
        }
    }
}

impl From<ModelKind> for PredictorKind {
    fn from(kind: ModelKind) -> Self {
        match kind {
            ModelKind::Teacher => Self::Teacher,
            ModelKind::Student => Self::Student,
        }
    }
}

impl std::fmt::Display for PredictorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Not one of the names of [`PredictorKind`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown predictor {0:?} (expected \"teacher\", \"student\" or \"constant_velocity\")")]
pub struct UnknownPredictor(pub String);

impl FromStr for PredictorKind {
    type Err = UnknownPredictor;

    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.as_str() == s)
            .ok_or_else(|| UnknownPredictor(s.to_string()))
    }
}

/// Where a checkout keeps the shipped assets, relative to the repository root: the assets of
/// the tools run from the root (the `nudge` binary, the examples, the tests).
pub const CHECKOUT_ASSETS: &str = "assets";

/// The assets directory (`models/`, `scenes/`) of a nudge whose shipped assets are at
/// `shipped`: `$NUDGE_ASSETS` when set and not empty, else `shipped`.
///
/// The one rule every front end resolves the assets through; only `shipped` differs: the
/// `nudge` binary and the Rust examples pass [`CHECKOUT_ASSETS`] ([`default_assets_dir`]),
/// the Python package `nudge` passes the `assets` folder inside the installed package (in a
/// checkout, `python/nudge/assets` links to `assets`), and so does its `nudge` command.
#[must_use]
pub fn assets_dir(shipped: impl Into<PathBuf>) -> PathBuf {
    assets_dir_from(std::env::var_os(ASSETS_ENV), shipped.into())
}

/// [`assets_dir`] with the environment variable's value given (`None`: not set).
fn assets_dir_from(env: Option<std::ffi::OsString>, shipped: PathBuf) -> PathBuf {
    env.filter(|v| !v.is_empty()).map_or(shipped, PathBuf::from)
}

/// The assets directory of the tools run from a checkout's root: `$NUDGE_ASSETS` when set and
/// not empty, else `assets` (relative to the working directory): [`assets_dir`] of
/// [`CHECKOUT_ASSETS`].
#[must_use]
pub fn default_assets_dir() -> PathBuf {
    assets_dir(CHECKOUT_ASSETS)
}

/// The shipped real scenes under the assets directory `assets`: `<assets>/scenes` (one
/// "nudge.scenario/1" `.safetensors` file per scene). The only place that knows this layout.
#[must_use]
pub fn scenes_dir(assets: &Path) -> PathBuf {
    assets.join("scenes")
}

/// The shipped weights of `kind` under the assets directory `assets`:
/// `<assets>/models/<teacher|student>.safetensors`. The only place that knows this layout.
#[must_use]
pub fn model_path(assets: &Path, kind: ModelKind) -> PathBuf {
    assets
        .join("models")
        .join(format!("{}.safetensors", kind.as_str()))
}

/// A predictor to build once per run: the weights are read and checked once, and every
/// [`PredictorSpec::build`] clones the loaded network.
#[derive(Debug, Clone)]
pub enum PredictorSpec {
    /// The constant-velocity baseline (its horizon checked at construction).
    ConstantVelocity(ConstantVelocity),
    /// A loaded teacher.
    Teacher(Box<Teacher>),
    /// A loaded student.
    Student(Box<Student>),
}

impl PredictorSpec {
    /// A teacher or a student loaded from a weights file, whichever its config names.
    ///
    /// # Errors
    /// Any loading error of [`ModelWeights::from_file`].
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        let w = ModelWeights::from_file(path)?;
        Ok(match w.config().kind {
            ModelKind::Teacher => Self::Teacher(Box::new(Teacher::from_weights(&w)?)),
            ModelKind::Student => Self::Student(Box::new(Student::from_weights(&w)?)),
        })
    }

    /// `name_or_path`: `"constant_velocity"` (with `horizon` steps), `"teacher"` or
    /// `"student"` (the shipped weights under `assets`, [`model_path`]), or the path of a
    /// weights file. A constant-velocity baseline or a teacher predicts `horizon` steps
    /// (the teacher rolls its one-step network out `horizon` times, [`Teacher::set_horizon`]);
    /// a student keeps its fixed horizon, which the planner's settings check
    /// ([`PredictorSpec::with_horizon`] refuses any other).
    ///
    /// # Errors
    /// Any loading error; [`PredictorError::WrongModelKind`] when a named model's file holds
    /// the other kind of network; [`PredictorError::Horizon`] for a horizon outside
    /// `1..=MAX_HORIZON`.
    ///
    /// # Examples
    ///
    /// ```
    /// use nudge_predictor::{PredictorKind, PredictorSpec};
    ///
    /// let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets");
    /// let student = PredictorSpec::resolve("student", &assets, 6)?;
    /// assert_eq!(student.kind(), PredictorKind::Student);
    /// // Every build is a fresh predictor with the same weights.
    /// let (a, b) = (student.build(), student.build());
    /// assert_eq!((a.name(), b.horizon()), ("student", 6));
    /// assert_eq!(PredictorSpec::resolve("constant_velocity", &assets, 6)?.horizon(), 6);
    /// # Ok::<(), nudge_predictor::PredictorError>(())
    /// ```
    pub fn resolve(name_or_path: impl AsRef<Path>, assets: &Path, horizon: usize) -> Result<Self> {
        let given = name_or_path.as_ref();
        let kind = given.to_str().and_then(|s| s.parse::<PredictorKind>().ok());
        match kind {
            Some(PredictorKind::ConstantVelocity) => {
                Ok(Self::ConstantVelocity(ConstantVelocity::new(horizon)?))
            }
            Some(k) => {
                let model = k.model().unwrap_or(ModelKind::Teacher);
                let path = model_path(assets, model);
                let spec = Self::from_file(&path)?;
                if spec.kind() != k {
                    return Err(PredictorError::WrongModelKind {
                        path,
                        expected: k.as_str(),
                        got: spec.kind().as_str(),
                    });
                }
                spec.with_teacher_horizon(horizon)
            }
            None => Self::from_file(given)?.with_teacher_horizon(horizon),
        }
    }

    /// The same predictor for `horizon` steps: a constant-velocity baseline or a teacher
    /// (a longer or shorter recursive roll-out of the same network) for any horizon, a
    /// student only for its own.
    ///
    /// # Errors
    /// [`PredictorError::Horizon`] outside `1..=MAX_HORIZON`; [`PredictorError::FixedHorizon`]
    /// when a student is asked for a horizon other than the one its network decodes.
    ///
    /// # Examples
    ///
    /// ```
    /// use nudge_predictor::{PredictorError, PredictorSpec};
    ///
    /// let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets");
    /// let teacher = PredictorSpec::resolve("teacher", &assets, 6)?.with_horizon(10)?;
    /// assert_eq!(teacher.build().horizon(), 10);
    /// let student = PredictorSpec::resolve("student", &assets, 6)?;
    /// assert!(matches!(
    ///     student.with_horizon(10),
    ///     Err(PredictorError::FixedHorizon { predictor: "student", got: 10, predicts: 6 })
    /// ));
    /// # Ok::<(), nudge_predictor::PredictorError>(())
    /// ```
    pub fn with_horizon(self, horizon: usize) -> Result<Self> {
        check_horizon(horizon)?;
        match self {
            Self::Student(s) if s.horizon() != horizon => Err(PredictorError::FixedHorizon {
                predictor: "student",
                got: horizon,
                predicts: s.horizon(),
            }),
            Self::Student(_) => Ok(self),
            other => other.with_teacher_horizon(horizon),
        }
    }

    /// `horizon` for a constant-velocity baseline or a teacher; a student unchanged.
    fn with_teacher_horizon(self, horizon: usize) -> Result<Self> {
        Ok(match self {
            Self::ConstantVelocity(_) => Self::ConstantVelocity(ConstantVelocity::new(horizon)?),
            Self::Teacher(t) => Self::Teacher(Box::new(t.with_horizon(horizon)?)),
            Self::Student(s) => Self::Student(s),
        })
    }

    /// Which kind of predictor this builds.
    #[must_use]
    pub fn kind(&self) -> PredictorKind {
        match self {
            Self::ConstantVelocity(_) => PredictorKind::ConstantVelocity,
            Self::Teacher(_) => PredictorKind::Teacher,
            Self::Student(_) => PredictorKind::Student,
        }
    }

    /// Prediction horizon (steps).
    #[must_use]
    pub fn horizon(&self) -> usize {
        match self {
            Self::ConstantVelocity(cv) => cv.horizon(),
            Self::Teacher(t) => t.horizon(),
            Self::Student(s) => s.horizon(),
        }
    }

    /// A fresh predictor (a clone of the loaded network).
    #[must_use]
    pub fn build(&self) -> Box<dyn Predictor> {
        match self {
            Self::ConstantVelocity(cv) => Box::new(cv.clone()),
            Self::Teacher(t) => Box::new(t.as_ref().clone()),
            Self::Student(s) => Box::new(s.as_ref().clone()),
        }
    }
}

#[cfg(test)]
mod tests {
    use std::ffi::OsString;
    use std::path::{Path, PathBuf};

    use super::{assets_dir_from, model_path, scenes_dir};
    use crate::weights::ModelKind;

    #[test]
    fn the_variable_overrides_the_shipped_assets_unless_empty() {
        let shipped = PathBuf::from("/opt/site-packages/nudge/assets");
        assert_eq!(assets_dir_from(None, shipped.clone()), shipped);
        assert_eq!(
            assets_dir_from(Some(OsString::new()), shipped.clone()),
            shipped
        );
        assert_eq!(
            assets_dir_from(Some(OsString::from("/data/mine")), shipped),
            PathBuf::from("/data/mine")
        );
    }

    #[test]
    fn models_and_scenes_lie_in_their_folders_of_the_assets() {
        let a = Path::new("x");
        assert_eq!(
            model_path(a, ModelKind::Student),
            Path::new("x/models/student.safetensors")
        );
        assert_eq!(
            model_path(a, ModelKind::Teacher),
            Path::new("x/models/teacher.safetensors")
        );
        assert_eq!(scenes_dir(a), Path::new("x/scenes"));
    }
}
