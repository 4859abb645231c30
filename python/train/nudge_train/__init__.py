"""nudge_train: training, data pipeline and evaluation for the nudge planner."""
