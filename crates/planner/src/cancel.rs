//! A cancellation flag for work that runs on another thread than the one that may stop it
//! (a Ctrl-C handler, a time limit): [`Cancel`].

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// A cancellation flag: once [`Cancel::cancel`] is called, a [`crate::Planner`] holding it
/// ([`crate::Planner::set_cancel`]) ends its call within one predictor call with
/// [`crate::PlannerError::Cancelled`], and a closed-loop run holding it stops before its next
/// step. Clones share the flag. Setting it is the only way it changes a call: a call it never
/// stops is the same, bit for bit, as one without it.
#[derive(Debug, Clone, Default)]
pub struct Cancel(Arc<AtomicBool>);

impl Cancel {
    /// A flag not set.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the flag (from any thread).
    pub fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }

    /// Whether the flag is set.
    #[must_use]
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}
