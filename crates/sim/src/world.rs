//! What moves the other vehicles of a run: the world model handed to [`crate::simulate`]
//! ([`WorldModel`]) and the per-run mover built from it.

use nudge_predictor::{History, Predictor, T_OBS};

use crate::error::SimError;
use nudge_planner::State;
use nudge_planner::scenario::Scenario;

use super::config::{SimConfig, World};
use super::idm::{IdmPopulation, IdmTraffic};

/// The model that moves the other vehicles of one run; it must match
/// [`SimConfig::world`].
pub enum WorldModel<'a> {
    /// A [`World::LogReplay`] world needs none: the log moves them.
    LogReplay,
    /// A [`World::Teacher`] world: the teacher that predicts them.
    Teacher(&'a mut dyn Predictor),
    /// A [`World::Idm`] world: the driver population they draw from.
    Idm(&'a IdmPopulation),
}

impl WorldModel<'_> {
    /// The world this model moves.
    #[must_use]
    pub fn world(&self) -> World {
        match self {
            Self::LogReplay => World::LogReplay,
            Self::Teacher(_) => World::Teacher,
            Self::Idm(_) => World::Idm,
        }
    }

    /// What the model is, for messages.
    fn describe(&self) -> String {
        match self {
            Self::LogReplay => "none".into(),
            Self::Teacher(p) => format!("a {} predictor", p.name()),
            Self::Idm(p) => format!("the IDM population {}", p.path.display()),
        }
    }
}

impl std::fmt::Debug for WorldModel<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.describe())
    }
}

/// What moves the other vehicles during one run (its per-run state; a teacher world's
/// predictor is handed to every step).
pub(crate) enum Mover {
    /// The teacher's interactive prediction: its buffers.
    Teacher {
        candidate: Vec<f64>,
        prediction: Vec<f64>,
    },
    /// The logged future, and the lateral decay past its end
    /// ([`SimConfig::replay_lateral_decay`]).
    LogReplay {
        /// Fraction of the last lateral displacement repeated per extrapolated step.
        lateral_decay: f64,
    },
    /// IDM traffic.
    Idm(IdmTraffic),
}

/// Checks that `model` is the model of `cfg.world` (a teacher world's a teacher).
///
/// # Errors
/// [`SimError::WorldModel`] naming the world and what was given.
pub(crate) fn check(cfg: &SimConfig, model: &WorldModel<'_>) -> Result<(), SimError> {
    if model.world() != cfg.world {
        return Err(SimError::WorldModel {
            world: cfg.world.as_str(),
            reason: match cfg.world {
                World::Teacher => format!(
                    "needs a teacher to move the others, got {}",
                    model.describe()
                ),
                World::Idm => format!("needs an IDM driver population, got {}", model.describe()),
                World::LogReplay => format!(
                    "the logged future moves the others; {} would be ignored",
                    model.describe()
                ),
            },
        });
    }
    if let WorldModel::Teacher(predictor) = model
        && predictor.name() != "teacher"
    {
        return Err(SimError::WorldModel {
            world: World::Teacher.as_str(),
            reason: format!(
                "the world model must be a teacher, got a {}",
                predictor.name()
            ),
        });
    }
    Ok(())
}

impl Mover {
    /// The mover of `cfg.world` for the run of scene `sc` with `seed`, checked against the
    /// model given ([`check`]).
    pub(crate) fn new(
        cfg: &SimConfig,
        model: &WorldModel<'_>,
        sc: &Scenario,
        seed: u64,
        horizon: usize,
    ) -> Result<Self, SimError> {
        check(cfg, model)?;
        Ok(match model {
            WorldModel::Teacher(_) => Self::Teacher {
                candidate: vec![0.0; horizon * 2],
                prediction: vec![0.0; (sc.n_agents.max(2) - 1) * horizon * 2],
            },
            WorldModel::LogReplay => Self::LogReplay {
                lateral_decay: cfg.replay_lateral_decay,
            },
            WorldModel::Idm(population) => Self::Idm(IdmTraffic::new(sc, population, seed)),
        })
    }

    /// The others' positions after `step` (index = agent, agent 0 = the ego at `ego_to`): the
    /// teacher `world` predicts them given the ego's executed position and the rest of its
    /// `plan`; log replay reads the log (past its end, the last two observations'
    /// displacement along the road and a decaying share of it across); IDM traffic follows
    /// its leaders while the ego moves from `ego_from` to `ego_to`. `world` must have passed
    /// [`check`].
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn advance(
        &mut self,
        sc: &Scenario,
        world: &mut WorldModel<'_>,
        history: &History,
        view: &[usize],
        observed: &[Vec<[f64; 2]>],
        step: usize,
        ego_from: &State,
        ego_to: &State,
        plan: &[[f64; 4]],
    ) -> Result<Vec<[f64; 2]>, SimError> {
        let n = sc.n_agents;
        let mut moved: Vec<[f64; 2]> = Vec::with_capacity(n);
        moved.push([ego_to[0], ego_to[1]]);
        match self {
            Self::Teacher { .. } if n < 2 => {}
            Self::Teacher {
                candidate,
                prediction,
            } => {
                let WorldModel::Teacher(predictor) = world else {
                    return Err(SimError::WorldModel {
                        world: World::Teacher.as_str(),
                        reason: format!(
                            "needs a teacher to move the others, got {}",
                            world.describe()
                        ),
                    });
                };
                let horizon = candidate.len() / 2;
                candidate[0] = ego_to[0];
                candidate[1] = ego_to[1];
                for k in 1..horizon {
                    candidate[2 * k] = plan[k][0];
                    candidate[2 * k + 1] = plan[k][1];
                }
                if view.len() < n {
                    // Agents outside the view (farther than the predictors' span,
                    // `run::view_of`) keep their last observed displacement per step.
                    let m = view.len() - 1;
                    let mut predicted = Vec::with_capacity(m);
                    if m > 0 {
                        let out = &mut prediction[..m * horizon * 2];
                        predictor
                            .set_scene(history)
                            .and_then(|()| predictor.predict(candidate, out))
                            .map_err(|source| SimError::Predictor {
                                scene: sc.name.clone(),
                                source,
                            })?;
                        predicted.extend((0..m).map(|j| {
                            let b = j * horizon * 2;
                            [out[b], out[b + 1]]
                        }));
                    }
                    for (i, seen) in observed.iter().enumerate().skip(1) {
                        moved.push(match view.iter().position(|&v| v == i) {
                            Some(j) => predicted[j - 1],
                            None => crate::run::constant_velocity(seen, 1)[0],
                        });
                    }
                } else {
                    predictor
                        .set_scene(history)
                        .and_then(|()| predictor.predict(candidate, prediction))
                        .map_err(|source| SimError::Predictor {
                            scene: sc.name.clone(),
                            source,
                        })?;
                    for i in 1..n {
                        let b = (i - 1) * horizon * 2;
                        moved.push([prediction[b], prediction[b + 1]]);
                    }
                }
            }
            Self::LogReplay { lateral_decay } => {
                for (i, h) in observed.iter().enumerate().skip(1) {
                    moved.push(logged_position(sc, i, h, step, *lateral_decay));
                }
            }
            Self::Idm(traffic) => moved.extend(traffic.step(ego_from, ego_to)),
        }
        Ok(moved)
    }
}

/// Where the log puts `agent` after closed-loop step `step` (m): its logged position at future
/// step `step + 1`, or, where the log has none, its last observed position `observed[T_OBS −
/// 1]` (m) moved by the displacement from `observed[T_OBS − 2]` along the road (x) and by
/// `lateral_decay` (in [0, 1]) times it across (y). Applied step after step, a vehicle whose
/// log ends after a lateral displacement Δy is Δy·ρ(1 − ρᵏ)/(1 − ρ) further across k steps
/// later (ρ = `lateral_decay`; k·Δy at ρ = 1). The one rule of log replay (the simulator's
/// world, and the `LoggedTraffic` of the log-replay oracle in `nudge-research`).
#[must_use]
pub fn logged_position(
    sc: &Scenario,
    agent: usize,
    observed: &[[f64; 2]],
    step: usize,
    lateral_decay: f64,
) -> [f64; 2] {
    sc.future_at(agent, step + 1).unwrap_or_else(|| {
        let a = observed[T_OBS - 2];
        let b = observed[T_OBS - 1];
        [2.0 * b[0] - a[0], b[1] + lateral_decay * (b[1] - a[1])]
    })
}
