"""The experiments and reports behind docs/results and docs/figures, each a ``nudge-train``
subcommand: :mod:`~nudge_train.experiments.teacher` (Table I, ``teacher``),
:mod:`~nudge_train.experiments.student` (distillation, ``student``),
:mod:`~nudge_train.experiments.closed_loop` (``closed-loop``), :mod:`~nudge_train.experiments.paper`
with ``paper_runs``, ``paper_report`` and ``paper_table2`` (``paper``: Tables I-II and Figures 7-10
into docs/paper), the benchmark tables
:mod:`~nudge_train.experiments.bench_inference`, :mod:`~nudge_train.experiments.bench_planner` and
:mod:`~nudge_train.experiments.bench_python` (``bench``), and :mod:`~nudge_train.experiments.plots`
(``figures``)."""
