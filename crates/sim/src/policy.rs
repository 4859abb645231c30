//! What drives the ego in a closed loop: a [`Policy`] receives the step's observation (a
//! [`PlanningProblem`]: the measured ego state, the observed histories, the lanes and the
//! goal) and returns a [`Plan`], whose first input the simulator applies. nudge's
//! [`Planner`] is one; another planner can be driven through the same loop
//! ([`crate::simulate_policy`]).

use nudge_planner::{Plan, Planner, PlannerError, PlanningProblem};
use nudge_predictor::Predictor;

/// A motion planner the simulator can drive: observation in, plan out.
pub trait Policy {
    /// Forgets everything carried between steps (warm starts); called before a run's first
    /// step.
    fn reset(&mut self);

    /// Plans the ego's motion for one closed-loop step. `predictor` is the planning
    /// predictor of the run (the policy may call it to predict the others' reactions).
    ///
    /// # Errors
    /// A [`PlannerError`] when the problem cannot be planned; the run stops with it.
    fn plan(
        &mut self,
        problem: &PlanningProblem<'_>,
        predictor: &mut dyn Predictor,
    ) -> Result<Plan, PlannerError>;
}

impl Policy for Planner {
    fn reset(&mut self) {
        Planner::reset(self);
    }

    fn plan(
        &mut self,
        problem: &PlanningProblem<'_>,
        predictor: &mut dyn Predictor,
    ) -> Result<Plan, PlannerError> {
        Planner::plan(self, problem, predictor)
    }
}
