"""``nudge-train``: the one command of the training package.

Its subcommands (data pipeline, training, distillation, experiments, benches, golden files,
figures, CommonRoad checks, the IDM world's fit) are registered in :func:`build_parser`, and
``nudge-train --help`` lists them from that registration, each with its one-line help: the parser
is the only list of them.

Default paths come from :mod:`nudge_train.paths` (``NUDGE_REPO``, ``NUDGE_ASSETS``,
``NUDGE_NGSIM``). This module imports only the standard library and the light configuration
modules: each subcommand imports what it needs when it runs, so ``--help`` is instant and
``figures`` works without torch.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from nudge_train import paths
from nudge_train.constants import BENCH_NS, DEFAULT_ROAD_FRAME, ROAD_FRAMES, SPLITS

__all__ = ["build_parser", "main"]

Handler = Callable[[argparse.Namespace], int]


class _Formatter(argparse.HelpFormatter):
    """Help with every option's default, where it has one."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if action.option_strings and default is not None and default is not False and default != [] \
                and default is not argparse.SUPPRESS:
            text += " (default: %(default)s)"
        return text


def _subcommands(parser: argparse.ArgumentParser, dest: str) -> argparse._SubParsersAction:
    """The subcommands of ``parser``. Its help lists them from their registration (``add_parser``
    with a ``help``), each with its one-line help, under "commands"; nothing else names them."""
    return parser.add_subparsers(dest=dest, required=True, title="commands", metavar="COMMAND")


class _DocPath(type(Path())):
    """The default of an output argument under the tracked ``docs/`` (so an argument the user did
    not give can be told from one they did): :func:`main` redirects it (:func:`untracked`)."""


class _DocStr(str):
    """:class:`_DocPath` for an argument read as a string."""

    __slots__ = ()


def _doc(path: Path) -> Path:
    return _DocPath(path)


def _doc_str(path: Path) -> str:
    return _DocStr(path)


def untracked(path: Path) -> Path:
    """Where an output under the tracked ``docs/`` goes when its argument is not given:
    ``<repo>/runs/reports/<its path under docs/>`` (not tracked)."""
    try:
        rel = Path(path).relative_to(paths.docs())
    except ValueError:
        rel = Path(Path(path).name)
    return paths.runs() / "reports" / rel


def _redirect_tracked_defaults(args: argparse.Namespace) -> None:
    """No command overwrites a tracked document unless asked: every output argument left at its
    default under ``docs/`` is moved to :func:`untracked`, with a note on stderr naming the flag
    that writes the tracked file."""
    for key, value in vars(args).items():
        if isinstance(value, (_DocPath, _DocStr)):
            moved = untracked(Path(value))
            setattr(args, key, str(moved) if isinstance(value, str) else moved)
            flag = "--" + key.replace("_", "-")
            print(f"note: writing {moved} (the tracked {paths.repo_relative(Path(value))} is written only when named: "
                  f"{flag} {paths.repo_relative(Path(value))})", file=sys.stderr)


def _command(sub: argparse._SubParsersAction, name: str, help_text: str, run: Handler) -> argparse.ArgumentParser:
    p = sub.add_parser(name, help=help_text, description=help_text, formatter_class=_Formatter)
    p.set_defaults(run=run)
    return p


# ---- data -------------------------------------------------------------------------------------
def _add_data(sub: argparse._SubParsersAction) -> None:
    data = sub.add_parser("data", help="NGSIM data pipeline", description="NGSIM data pipeline")
    dsub = _subcommands(data, "data_cmd")

    b = _command(dsub, "build", "build training windows (safetensors shards + manifest)", _run_data_build)
    b.add_argument("--data-root", type=Path, default=paths.ngsim(), help="raw NGSIM material")
    b.add_argument("--out", type=Path, default=paths.processed(), help="output folder")
    b.add_argument("--raw", type=Path, action="append", default=[],
                   help="extra official raw NGSIM file(s) (18- or 25-column, feet) to include")
    b.add_argument("--seed", type=int, default=0, help="seed of the split assignment")
    b.add_argument("--phases", type=str, default="0,1,2", help="0.1 s phase offsets, e.g. 0 or 0,1,2")
    b.add_argument("--no-i80", action="store_true", help="leave out the Coifman & Li I-80 set")
    b.add_argument("--frame", choices=ROAD_FRAMES, default=DEFAULT_ROAD_FRAME,
                   help="road frame of the US-101 scenes: frenet (curvilinear, lanes that begin and end), or "
                        "straightened (the older frame)")
    b.add_argument("--n-fut", type=int, default=None,
                   help="future steps (0.3 s) per window (default 6; e.g. 10 for 3 s evaluations, into another --out)")
    b.add_argument("--no-progress", action="store_true", help="no progress bar")

    r = _command(dsub, "report", "write docs/data.md and docs/figures/data_*.png from a build", _run_data_report)
    r.add_argument("--processed", type=Path, default=paths.processed(), help="a processed build")
    r.add_argument("--doc", type=Path, default=_doc(paths.docs() / "data.md"), help="the report")
    r.add_argument("--figures", type=Path, default=_doc(paths.figures()), help="folder of the report's figures")
    r.add_argument("--scenes-root", type=Path, default=None,
                   help="planner scenes per split, for their counts (default PROCESSED/scenes)")

    s = _command(dsub, "scenes", "write planner scenarios (nudge.scenario/2 with lane extents, or /1 with "
                 "--frame straightened) of a split", _run_data_scenes)
    s.add_argument("--data-root", type=Path, default=paths.ngsim(), help="raw NGSIM material")
    s.add_argument("--split", choices=SPLITS, default="test", help="the split written")
    s.add_argument("--out", type=Path, default=None,
                   help="output folder (default data/processed/scenes/<split>, or assets/scenes with --ship)")
    s.add_argument("--ship", action="store_true", help="write the small shipped selection (8-12 scenarios)")
    s.add_argument("--frame", choices=ROAD_FRAMES, default=DEFAULT_ROAD_FRAME,
                   help="road frame: frenet (curvilinear, nudge.scenario/2 with lane extents) or straightened "
                        "(nudge.scenario/1)")
    s.add_argument("--range", type=float, default=60.0, help="neighbour range (m)")
    s.add_argument("--seed", type=int, default=0, help="seed of the split assignment")
    s.add_argument("--no-progress", action="store_true", help="no progress bar")

    f = _command(dsub, "frames", "compare the straightened and curvilinear road frames per US-101 scene",
                 _run_data_frames)
    f.add_argument("--data-root", type=Path, default=paths.ngsim(), help="raw NGSIM material")
    f.add_argument("--doc", type=Path, default=_doc(paths.results() / "road_frame.md"), help="the table")
    f.add_argument("--seed", type=int, default=0, help="seed of the split assignment")
    f.add_argument("--no-progress", action="store_true", help="no progress bar")


def _run_data_frames(a: argparse.Namespace) -> int:
    from nudge_train.data.frame_cmd import write_frame_report
    from nudge_train.data.splits import SplitConfig

    rows = write_frame_report(a.data_root, a.doc, SplitConfig(seed=a.seed), progress=not a.no_progress)
    refused = [r for r in rows if r.after is None]
    print(f"wrote {a.doc}: {len(rows)} scenes, {len(refused)} refused by the curvilinear frame")
    return 0


def _run_data_build(a: argparse.Namespace) -> int:
    from nudge_train.data.build import BuildConfig, build

    from nudge_train.data.sources import decision_lines

    from nudge_train.data.windows import WindowConfig

    phases = tuple(int(p) for p in a.phases.split(",") if p.strip())
    if a.n_fut is not None and a.n_fut < 1:
        print(f"error: --n-fut must be >= 1, got {a.n_fut}", file=sys.stderr)
        return 2
    window = WindowConfig() if a.n_fut is None else WindowConfig(n_fut=a.n_fut)
    manifest = build(BuildConfig(data_root=a.data_root, out=a.out, raw=tuple(a.raw), seed=a.seed, phases=phases,
                                 include_i80=not a.no_i80, frame=a.frame, window=window), progress=not a.no_progress)
    print(f"wrote {a.out / 'manifest.json'}: {manifest['counts']['windows']} windows "
          f"(road frame {manifest['config']['road_frame']})")
    for split, sp in manifest["splits"].items():
        print(f"  {split}: {sp['windows']} windows, {sp['merge_windows']} merge windows (an agent in a lane that "
              "ends ahead)")
    res = [(s["reader_notes"]["lane_straightness_cm"], s["name"]) for s in manifest["sources"]
           if "lane_straightness_cm" in s.get("reader_notes", {})]
    if res:
        cm, name = max(res)
        print(f"  mapping residual of the lane map: at most {cm / 100:.2f} m ({name}); per scene in the manifest "
              "(reader_notes.lane_straightness_cm)")
    for line in decision_lines([(s["split"], s.get("rule", ""), s.get("reason", "")) for s in manifest["sources"]]):
        print(f"  {line}")
    return 0


def _run_data_report(a: argparse.Namespace) -> int:
    from nudge_train.data.report import write_report

    write_report(a.processed, a.doc, a.figures, a.scenes_root)
    print(f"wrote {a.doc}")
    return 0


def _run_data_scenes(a: argparse.Namespace) -> int:
    from nudge_train.data.scene_cmd import ScenesConfig, write_scenes
    from nudge_train.data.splits import SplitConfig

    out = a.out or (paths.shipped_scenes() if a.ship else paths.scenes(a.split))
    res = write_scenes(a.data_root, out, ScenesConfig(split=a.split, ship=a.ship, dense_range_m=a.range,
                                                      frame=a.frame),
                       SplitConfig(seed=a.seed), progress=not a.no_progress)
    ramps = sum(v.get("ramp_scenarios", 0) for v in res.per_scene.values()) if not a.ship else None
    print(f"wrote {len(res.written)} scenarios to {out} (road frame {a.frame}): {len(res.merges)} merge scenarios "
          "(ego in a lane that ends ahead)" + ("" if ramps is None else
                                              f", {ramps} on-ramp scenarios (ego in a lane that begins in the scene)"))
    for k, v in sorted(res.drops.items()):
        print(f"  dropped candidates ({k}): {v}")
    if res.removed:
        print(f"  removed {res.removed} scenario file(s) of an earlier run")
    for line in res.notes:
        print(f"  {line}")
    return 0


# ---- training and experiments ----------------------------------------------------------------
def _add_train(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "train", "train one configuration (TOML with [model] and [train] tables)", _run_train)
    p.add_argument("--config", type=Path, required=True, help="training config (TOML)")
    p.add_argument("--resume", action="store_true", help="continue from OUT_DIR/last.pt")
    p.add_argument("--out-dir", type=str, default=None, help="override train.out_dir")
    p.add_argument("--data", type=str, default=None, help="override train.data")
    p.add_argument("--epochs", type=int, default=None, help="override train.epochs")


def _run_train(a: argparse.Namespace) -> int:
    from nudge_train.training.loop import run

    return run(config=a.config, resume=a.resume, out_dir=a.out_dir, data=a.data, epochs=a.epochs)


def _add_teacher(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "teacher", "teacher experiments (Table I): train, select, evaluate, report, export",
                 _run_teacher)
    p.add_argument("--data", default=str(paths.processed()), help="processed build")
    p.add_argument("--runs", default=str(paths.runs()), help="one training run per config below it")
    p.add_argument("--epochs", type=int, default=None, help="override every config's epoch count")
    p.add_argument("--only", nargs="*", default=None, help="config names (e.g. teacher_k1_adv0)")
    p.add_argument("--report", default=_doc_str(paths.results() / "teacher.md"), help="the report (markdown)")
    p.add_argument("--export", default=str(paths.model_weights("teacher")), help="where the chosen teacher is exported")
    p.add_argument("--no-export", action="store_true", help="do not export")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")


def _run_teacher(a: argparse.Namespace) -> int:
    from nudge_train.experiments.teacher import run

    return run(data=a.data, runs_dir=a.runs, epochs=a.epochs, only=a.only, report=a.report,
               export=None if a.no_export else a.export, threads=a.threads)


def _add_student(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "student", "distil the student from the teacher: train, evaluate, report, export",
                 _run_student)
    p.add_argument("--config", type=Path, default=paths.configs() / "student.toml", help="training config")
    p.add_argument("--distill", default=str(paths.distill()), help="the distillation set")
    p.add_argument("--data", default=str(paths.processed()), help="real NGSIM windows (test split)")
    p.add_argument("--out-dir", default=str(paths.runs() / "student"), help="the training run")
    p.add_argument("--epochs", type=int, default=None, help="override the config's epoch count")
    p.add_argument("--teacher", default=str(paths.model_weights("teacher")),
                   help="the teacher the distillation set was generated with")
    p.add_argument("--report", default=_doc_str(paths.results() / "student.md"), help="the report (markdown)")
    p.add_argument("--export", default=str(paths.model_weights("student")), help="where the student is exported")
    p.add_argument("--no-export", action="store_true", help="do not export")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")


def _run_student(a: argparse.Namespace) -> int:
    from nudge_train.experiments.student import run

    return run(config=a.config, distill=a.distill, data=a.data, out_dir=a.out_dir, epochs=a.epochs,
               teacher=a.teacher, report=a.report, export=None if a.no_export else a.export, threads=a.threads)


def _add_student_report(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "student-report",
                 "the report of a trained student (default the shipped one): fidelity, reaction and accuracy against "
                 "the teacher, how it was trained: docs/results/student.md", _run_student_report)
    p.add_argument("--weights", type=Path, default=paths.model_weights("student"), help="the student")
    p.add_argument("--teacher", type=Path, default=paths.model_weights("teacher"),
                   help="the teacher the distillation set was generated with")
    p.add_argument("--distill", type=Path, default=paths.distill(),
                   help="the distillation set the student was trained on (its test split is scored)")
    p.add_argument("--data", type=Path, default=paths.processed(), help="real NGSIM windows (test split)")
    p.add_argument("--report", type=Path, default=_doc(paths.results() / "student.md"), help="the report (markdown)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")


def _run_student_report(a: argparse.Namespace) -> int:
    from nudge_train.experiments.student import report

    return report(weights=a.weights, teacher=a.teacher, distill=a.distill, data=a.data, out=a.report,
                  threads=a.threads)


def _add_student_react(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "student-react",
                 "distil a student with a loss on its reaction to the ego candidate (select on validation, export)",
                 _run_student_react)
    p.add_argument("--config", type=Path, default=paths.configs() / "student_react.toml", help="training config")
    p.add_argument("--out-dir", default=None, help="override the config's out_dir")
    p.add_argument("--steps", type=int, default=None, help="override the config's optimiser steps")
    p.add_argument("--time-budget", type=float, default=None, help="override the config's time_budget_s (s)")
    p.add_argument("--export", default=None, help="where the student is exported (default: <out_dir>/student.safetensors)")


def _run_student_react(a: argparse.Namespace) -> int:
    from nudge_train.training.reaction import run

    return run(config=a.config, out_dir=a.out_dir, steps=a.steps, time_budget_s=a.time_budget, export=a.export)


def _add_reaction(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "reaction",
                 "reaction of the teacher and students to the ego: real cut-ins and held-out planner candidates",
                 _run_reaction)
    p.add_argument("--distill", type=Path, default=paths.distill(), help="the distillation set (its test split)")
    p.add_argument("--scenes-root", type=Path, default=paths.processed() / "scenes", help="planner scenes per split")
    p.add_argument("--split", default="test", choices=SPLITS, help="split of the planner candidates")
    p.add_argument("--cutins", type=Path, default=paths.assets() / "worlds" / "cutins.json", help="the real cut-ins")
    p.add_argument("--data-root", type=Path, default=paths.ngsim(), help="raw NGSIM material (the cut-ins' tracks)")
    p.add_argument("--teacher", type=Path, default=paths.model_weights("teacher"), help="teacher weights")
    p.add_argument("--student", type=Path, default=paths.model_weights("student"), help="the shipped student")
    p.add_argument("--candidate", action="append", default=[], metavar="NAME=PATH",
                   help="another student to measure, as name=weights (repeatable)")
    p.add_argument("--report", type=Path, default=_doc(paths.results() / "reaction.md"), help="the report (markdown)")
    p.add_argument("--json", type=Path, default=paths.runs() / "reaction" / "reaction.json",
                   help="every number of the report (JSON)")
    p.add_argument("--bootstrap", type=int, default=2000, help="bootstrap resamples")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")


def _run_reaction(a: argparse.Namespace) -> int:
    from nudge_train.experiments.reaction_report import run

    return run(a)


def _add_horizon(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "horizon",
                 "the teacher over a 3 s horizon: ADE/FDE at 1.8 s and 3.0 s, its reaction on real cut-ins, the "
                 "latency of the longer horizon: docs/results/horizon.md", _run_horizon)
    p.add_argument("--data", type=Path, default=paths.runs() / "processed_fut10",
                   help="a build with 10-step futures (`nudge-train data build --n-fut 10 --out DIR`)")
    p.add_argument("--teacher", type=Path, default=paths.model_weights("teacher"), help="teacher weights")
    p.add_argument("--samples", type=int, default=20, help="z draws of the best-of-k rows")
    p.add_argument("--best-of-n", type=int, default=200, help="test windows (seeded draw) of the best-of-k rows")
    p.add_argument("--cutins", type=Path, default=paths.assets() / "worlds" / "cutins.json", help="the real cut-ins")
    p.add_argument("--data-root", type=Path, default=paths.ngsim(), help="raw NGSIM material (the cut-ins' tracks)")
    p.add_argument("--latency", type=Path, default=None,
                   help="a report (docs/results/latency.md) holding a `nudge-train bench latency --horizons ...` section")
    p.add_argument("--report", type=Path, default=_doc(paths.results() / "horizon.md"), help="the report (markdown)")
    p.add_argument("--json", type=Path, default=paths.runs() / "horizon" / "horizon.json",
                   help="every number of the report (JSON)")
    p.add_argument("--bootstrap", type=int, default=2000, help="bootstrap resamples")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")


def _run_horizon(a: argparse.Namespace) -> int:
    from nudge_train.experiments.horizon import run

    return run(a)


def _size(text: str) -> dict[str, int | None]:
    from nudge_train.distill.config import parse_size

    try:
        return parse_size(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _add_distill(sub: argparse._SubParsersAction) -> None:
    from nudge_train.distill.config import DistillConfig

    d = DistillConfig()
    p = _command(sub, "distill", "generate the distillation set (planner + teacher; resumable, docs/distill.md)",
                 _run_distill)
    p.add_argument("--out", type=Path, default=d.out, help="output folder (shards + manifest.json)")
    p.add_argument("--splits", default=",".join(d.splits), help="comma-separated subset of train,val,test")
    p.add_argument("--size", type=_size, default="paper",
                   help="scenes per split: preset (tiny, small, first, paper = ~568k/113k/116k examples, all) "
                        "or train=N,val=N,test=N")
    p.add_argument("--teacher", type=Path, default=d.teacher, help="teacher weights (planning and labels)")
    p.add_argument("--scenes-root", type=Path, default=d.scenes_root,
                   help="planner scenes, one folder per split (written from --data-root when missing)")
    p.add_argument("--data-root", type=Path, default=d.data_root, help="raw NGSIM material")
    p.add_argument("--runs", type=int, default=d.runs, help="closed-loop runs per scene")
    p.add_argument("--seed", type=int, default=d.seed, help="seed of the scene order and target lanes")
    p.add_argument("--world", choices=("teacher", "log_replay"), default=d.world,
                   help="how the other vehicles move")
    p.add_argument("--max-steps", type=int, default=d.max_steps, help="closed-loop steps per run")
    p.add_argument("--scenes-per-shard", type=int, default=d.scenes_per_shard, help="scenes per shard")
    p.add_argument("--threads", type=int, default=None, help="rayon threads (default: all cores)")
    p.add_argument("--ray-address", default=None, help="run shards as Ray tasks on this cluster ('auto', 'ray://...')")
    p.add_argument("--ray-local", action="store_true", help="start a local Ray instance for the shards")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--stats", action="store_true",
                   help="only print the statistics of the set in --out (JSON and the docs/distill.md tables)")


def _run_distill(a: argparse.Namespace) -> int:
    import json
    from dataclasses import replace

    from nudge_train.distill.config import DistillConfig
    from nudge_train.distill.stats import describe, markdown

    if a.stats:
        stats = describe(a.out)
        print(json.dumps(stats, indent=1))
        print(markdown(stats))
        return 0
    try:
        cfg = replace(DistillConfig(), out=a.out, splits=tuple(s for s in a.splits.split(",") if s),
                      teacher=a.teacher, scenes_root=a.scenes_root, data_root=a.data_root, max_scenes=a.size,
                      runs=a.runs, seed=a.seed, world=a.world, max_steps=a.max_steps,
                      scenes_per_shard=a.scenes_per_shard, threads=a.threads, progress=not a.no_progress)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    from nudge_train.distill.pipeline import generate

    try:
        manifest = generate(cfg, ray_address=a.ray_address, use_ray=a.ray_local)
    except (FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(json.dumps(describe(cfg.out, manifest), indent=1))
    return 0


def _add_closed_loop(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "closed-loop",
                 "planners x worlds x seeds on a split's scenes, paired by (scene, seed): the report (printed; "
                 "--out writes it, e.g. docs/results/closed_loop.md)",
                 _run_closed_loop)
    p.add_argument("--split", choices=SPLITS, default="val", help="the split whose scenes run")
    p.add_argument("--scenes", type=Path, default=None,
                   help="folder of scenario files (default data/processed/scenes/<split>)")
    p.add_argument("--n", type=int, default=None, help="scenes drawn (seeded; default all)")
    p.add_argument("--seeds", type=int, default=3, help="runs (target-lane seeds) per scene")
    p.add_argument("--planners", nargs="+", default=["student", "teacher"],
                   help="planning predictors (teacher, student, constant_velocity or weights files)")
    p.add_argument("--worlds", nargs="+", choices=("teacher", "idm", "log_replay"),
                   default=["teacher", "idm", "log_replay"], help="worlds that move the other vehicles")
    p.add_argument("--teacher-n", type=int, default=60,
                   help="scenes of the teacher planner's seeded subset (>= 1 when the teacher plans; any >= 0 otherwise)")
    p.add_argument("--settings", type=Path, default=None, help="planner settings JSON (missing fields default)")
    p.add_argument("--config", type=Path, default=None,
                   help="closed-loop settings JSON (SimConfig; the world is set per arm)")
    p.add_argument("--compare", type=Path, nargs=2, default=None, metavar=("SETTINGS_A", "SETTINGS_B"),
                   help="run every planner x world with two planner settings and compare B with A")
    p.add_argument("--ablate-reaction", action="store_true",
                   help="every arm with the planner setting ablate_reaction on: the planner's predictor sees the "
                        "ego's keep-lane path instead of each candidate")
    p.add_argument("--reference", default=None,
                   help="planner the others are compared with (default: the first of --planners)")
    p.add_argument("--seed", type=int, default=0, help="seed of the scene draw, the scene seeds and the teacher subset")
    p.add_argument("--threads", type=int, default=2, help="runs side by side (with --ray and no address: the local "
                   "Ray's CPUs)")
    p.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                   help="compute the runs as Ray tasks, identical run by run: on a local Ray (no ADDRESS) or on the "
                        "cluster at ADDRESS ('auto', 'ray://head:10001'); docs/ray.md")
    p.add_argument("--ray-chunk", type=int, default=8, help="(scene, seed) runs per Ray task")
    p.add_argument("--batch", type=int, default=30, help="scenes per cached part of a chunk")
    p.add_argument("--cache", type=Path, default=paths.runs() / "closed_loop", help="cache of the runs")
    p.add_argument("--bootstrap", type=int, default=2000, help="bootstrap resamples of every interval")
    p.add_argument("--out", type=Path, default=None,
                   help="also write the report here (default: only print it; tracked docs are written only when named)")
    p.add_argument("--json", type=Path, default=None, dest="json_path", metavar="JSON",
                   help="also write the summaries here")
    p.add_argument("--before", nargs=2, default=None, metavar=("JSON", "LABEL"),
                   help="summaries of an earlier run (its --json) on the same arms, and what it was: adds a "
                        "before-and-after section")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")


def _run_closed_loop(a: argparse.Namespace) -> int:
    from nudge_train.experiments.closed_loop import EvalConfig, command_line, run

    try:
        cfg = EvalConfig(scenes=a.scenes or paths.scenes(a.split), n=a.n, seeds=a.seeds, planners=tuple(a.planners),
                         worlds=tuple(a.worlds), teacher_n=a.teacher_n, settings=a.settings, config=a.config,
                         compare=tuple(a.compare) if a.compare else None, reference=a.reference, seed=a.seed,
                         threads=a.threads, batch=a.batch, cache=a.cache, bootstrap=a.bootstrap,
                         progress=not a.no_progress, ablate_reaction=a.ablate_reaction, ray=a.ray,
                         ray_chunk=a.ray_chunk)
        cfg.validate()
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    before = (Path(a.before[0]), a.before[1]) if a.before else None
    return run(cfg, a.out, a.json_path, command_line(sys.argv[2:] if len(sys.argv) > 2 else []), before)


def _add_slow_plans(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "slow-plans",
                 "re-simulate the runs of a closed-loop cache with a plan ending slow on a free road and describe "
                 "what each such plan brakes for",
                 _run_slow_plans)
    p.add_argument("--split", choices=SPLITS, default="val", help="the split whose scenes the cache ran")
    p.add_argument("--scenes", type=Path, default=None,
                   help="folder of scenario files (default data/processed/scenes/<split>)")
    p.add_argument("--cache", type=Path, default=paths.runs() / "closed_loop", help="the closed-loop cache")
    p.add_argument("--out", type=Path, default=None, help="write the report here (default: print it)")
    p.add_argument("--json", type=Path, default=None, dest="json_path", metavar="JSON",
                   help="also write one row per flagged step here")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")


def _run_slow_plans(a: argparse.Namespace) -> int:
    import shlex

    from nudge_train.experiments.slow_plans import run

    command = "nudge-train slow-plans " + shlex.join(sys.argv[2:] if len(sys.argv) > 2 else [])
    try:
        return run(a.cache, a.scenes or paths.scenes(a.split), a.out, a.json_path, command,
                   progress=not a.no_progress)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


# ---- settings chosen across scene groups ------------------------------------------------------
def _add_group_cv(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "group-cv",
                 "planner-settings arms on a per-group sample of the training and validation scenes, every world, "
                 "paired with the base arm; chosen by the worst scene group, with leave-one-group-out (resumes "
                 "from verified records)",
                 _run_group_cv)
    p.add_argument("--arm", action="append", default=[], metavar="NAME=SETTINGS.json",
                   help="an arm: a name and a (partial) planner settings JSON; repeatable")
    p.add_argument("--base", default="defaults", metavar="NAME[=SETTINGS.json]",
                   help="the base arm every arm is paired with (default: the shipped defaults)")
    p.add_argument("--scenes", type=Path, default=None,
                   help="folder of scenario files (default: a sample of --per-group scenes of every group of the "
                        "train and val splits, written to OUT/scenes)")
    p.add_argument("--per-group", type=int, default=20, help="scenes per group of the sample")
    p.add_argument("--seed", type=int, default=0, help="seed of the sample")
    p.add_argument("--runs", type=int, default=3, help="target-lane seeds per scene")
    p.add_argument("--predictor", default="student", help="the planning predictor")
    p.add_argument("--nudge", type=Path, default=None, help="the nudge command (default: target/release/nudge)")
    p.add_argument("--out", type=Path, default=paths.runs() / "group_cv", help="folder of the arms' records")
    p.add_argument("--report", type=Path, default=None, help="write the report here (default OUT/report.md)")


def _parse_arm(text: str) -> tuple[str, dict]:
    from nudge_train.experiments.group_cv import GroupCvError

    name, sep, file = text.partition("=")
    if not name or not name.replace("_", "").replace("-", "").isalnum():
        raise GroupCvError(f"arm {text!r}: the name must be letters, digits, - or _")
    if not sep:
        return name, {}
    from nudge_train.jsonio import load_json

    settings = load_json(Path(file))
    if not isinstance(settings, dict):
        raise GroupCvError(f"arm {name}: {file} is not a JSON object")
    return name, settings


def _run_group_cv(a: argparse.Namespace) -> int:
    import shlex

    from nudge_train.experiments import group_cv as cv
    from nudge_train.nudge_command import CommandError, find_nudge

    command = "nudge-train group-cv " + shlex.join(sys.argv[2:] if len(sys.argv) > 2 else [])
    try:
        groups = cv.SceneGroups.from_manifest(paths.processed() / "manifest.json")
        base_name, base_settings = _parse_arm(a.base)
        arms = [cv.Arm(base_name, base_settings)] + [cv.Arm(*_parse_arm(x)) for x in a.arm]
        if len({x.name for x in arms}) != len(arms):
            raise cv.GroupCvError("two arms share a name")
        scenes = a.scenes
        if scenes is None:
            scenes = a.out / "scenes"
            counts = cv.sample_scenes([paths.scenes("train"), paths.scenes("val")], groups, a.per_group, a.seed,
                                      scenes)
            print(f"sample: {sum(counts.values())} scenes in {len(counts)} groups -> {scenes}")
        nudge = find_nudge(a.nudge)
        for arm in arms:
            cv.run_arm(nudge, arm, scenes.absolute(), a.runs, a.predictor, a.out.absolute())
        results = {arm.name: {w: cv.load_arm_world(a.out / arm.name / f"{a.predictor}-{w}", groups)
                              for w in cv.WORLDS} for arm in arms}
    except (cv.GroupCvError, CommandError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    text = cv.report(results, base_name, command)
    out = a.report or a.out / "report.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    choice, _ = cv.select(results, base_name)
    print(f"wrote {out}; chosen: {choice}")
    return 0


# ---- the paper ---------------------------------------------------------------------------------
def _add_paper(sub: argparse._SubParsersAction) -> None:
    from nudge_train.experiments.paper import STAGES, PaperConfig

    d = PaperConfig(out=Path("docs/paper"), cache=Path("runs/paper"), scenes=Path(), processed=Path(),
                    teacher_report=Path())
    p = _command(sub, "paper", "the paper's Tables I-II and Figures 7-10 regenerated into docs/paper "
                 "(resumable; every timing on one thread)", _run_paper)
    p.add_argument("--quick", action="store_true",
                   help="a check that the pipeline runs end to end (2 vehicle counts, a few short runs, a tiny "
                        "Table II), into runs/paper_quick unless --out / --cache are given")
    p.add_argument("--out", type=Path, default=None, help=f"output folder (default {d.out})")
    p.add_argument("--cache", type=Path, default=None, help=f"resumable intermediate results (default {d.cache})")
    p.add_argument("--stages", nargs="+", default=None, metavar="STAGE",
                   help=f"stages to run, among {' '.join(STAGES)} (default: all)")
    p.add_argument("--ns", nargs="+", type=int, default=None,
                   help=f"vehicle counts, ego included (default {' '.join(map(str, d.ns))})")
    p.add_argument("--sims", type=int, default=None,
                   help=f"closed-loop runs per vehicle count and predictor (default {d.sims})")
    p.add_argument("--seed", type=int, default=None,
                   help=f"seed of the scene draw and target lanes (default {d.seed})")
    p.add_argument("--threads", type=int, default=None,
                   help=f"threads of the distillation-set generation and the student training (default "
                        f"{d.threads}; timings always run on one)")
    p.add_argument("--students", nargs="+", default=None, metavar="NAME",
                   help="with --stages table2: train only these of Table II's students (e.g. student_k64_adv0), "
                        "so that several processes share the five trainings; nothing is written into --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def _run_paper(a: argparse.Namespace) -> int:
    from nudge_train.experiments.paper import PaperConfig, run

    over = {k: v for k, v in (("out", a.out), ("cache", a.cache), ("sims", a.sims), ("seed", a.seed),
                              ("threads", a.threads)) if v is not None}
    if a.stages is not None:
        over["stages"] = tuple(a.stages)
    if a.ns is not None:
        over["ns"] = tuple(a.ns)
    if a.students is not None:
        over["students"] = tuple(a.students)
    over["progress"] = not a.no_progress
    argv = sys.argv[2:] if len(sys.argv) > 2 and sys.argv[1] == "paper" else []
    try:
        cfg = (PaperConfig.quick_config(**over) if a.quick else PaperConfig(**over)).validate()
        return run(cfg, " ".join(["nudge-train", "paper", *argv]))
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


def _add_interaction(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "interaction",
                 "each planner aware vs the same model with its reaction ablated, on dense scenes, idm / teacher / "
                 "log_replay worlds, paired: docs/results/interaction.md", _run_interaction)
    p.add_argument("--splits", nargs="+", choices=SPLITS, default=["val", "test"], help="splits, in this order")
    p.add_argument("--n", type=int, nargs="+", default=[30, 60],
                   help="dense scenes drawn (seeded): one count for every split or one per split")
    p.add_argument("--teacher-n", type=int, nargs="+", default=[15, 30],
                   help="of these, scenes of the aware teacher planner: one count or one per split")
    p.add_argument("--seeds", type=int, default=3, help="runs (seeds drawing a blocked target lane) per scene")
    p.add_argument("--scenes", choices=("dense", "merge"), default="dense",
                   help="dense: the target lane blocked at the start; merge: the ego's lane really ends ahead of it")
    p.add_argument("--margin", type=float, default=2.0,
                   help="blocked: a target-lane vehicle overlaps the ego's longitudinal extent +- this (m)")
    p.add_argument("--candidate", type=Path, default=None,
                   help="weights of a candidate student, run aware and ablated as planner student_react")
    p.add_argument("--settings", type=Path, default=None,
                   help="planner settings JSON of every arm (missing fields default; ablate_reaction set per arm)")
    p.add_argument("--worlds", nargs="+", choices=("idm", "teacher", "log_replay"),
                   default=["idm", "teacher", "log_replay"], help="worlds")
    p.add_argument("--seed", type=int, default=0, help="seed of the scene seeds and the draws")
    p.add_argument("--threads", type=int, default=2, help="runs side by side")
    p.add_argument("--batch", type=int, default=10, help="scenes per cached part")
    p.add_argument("--cache", type=Path, default=paths.runs() / "interaction", help="cache of the runs")
    p.add_argument("--bootstrap", type=int, default=2000, help="bootstrap resamples of every interval")
    p.add_argument("--out", type=Path, default=_doc(paths.results() / "interaction.md"), help="the report")
    p.add_argument("--json", type=Path, default=paths.runs() / "interaction" / "interaction.json", dest="json_path",
                   metavar="JSON", help="the numbers of the report")
    p.add_argument("--horizon", type=int, default=None,
                   help="planning and prediction horizon of every arm (steps of 0.3 s; default the planner's, 6); "
                        "planners whose model cannot predict it (the 6-step students) are left out")
    p.add_argument("--compare-horizon", type=int, default=None,
                   help="also run every arm at this horizon on the same runs and pair the two in the report")
    p.add_argument("--no-figure", action="store_true", help="no figure or animations of a pair")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _run_interaction(a: argparse.Namespace) -> int:
    from nudge_train.experiments.interaction import InteractionConfig, command_line, run

    cfg = InteractionConfig(splits=tuple(a.splits), n=tuple(a.n), teacher_n=tuple(a.teacher_n), seeds=a.seeds,
                            margin=a.margin, scenes=a.scenes, candidate=a.candidate, settings=a.settings, worlds=tuple(a.worlds),
                            seed=a.seed,
                            threads=a.threads, batch=a.batch, cache=a.cache, bootstrap=a.bootstrap, progress=not a.no_progress,
                            animate=not a.no_figure, compare_horizon=a.compare_horizon,
                            **({} if a.horizon is None else {"horizon": a.horizon}))
    return run(cfg, a.out, a.json_path, command_line(sys.argv[2:] if len(sys.argv) > 2 else []))


# ---- benches, goldens, figures -----------------------------------------------------------------
def _add_bench(sub: argparse._SubParsersAction) -> None:
    bench = sub.add_parser("bench", help="benchmark tables", description="benchmark tables")
    bsub = _subcommands(bench, "bench_cmd")

    i = _command(bsub, "inference", "PyTorch vs Rust (criterion) inference times on the same weights and inputs",
                 _run_bench_inference)
    i.add_argument("--repo-root", type=Path, default=None,
                   help="read weights, bench scenes and criterion results below this root (default: nudge_train.paths)")
    i.add_argument("--criterion-dir", type=Path, default=None, help="default: <repo-root>/target/criterion")
    i.add_argument("--models", nargs="+", choices=("teacher", "student"), default=["teacher", "student"],
                   help="models timed")
    i.add_argument("--ns", nargs="+", type=int, default=list(BENCH_NS), help=f"agent counts, among {BENCH_NS}")
    i.add_argument("--batch32", action="store_true", help="32 candidates per call (group predictor_batch32)")
    i.add_argument("--warmup", type=int, default=10, help="untimed calls per configuration")
    i.add_argument("--repeats", type=int, default=50, help="minimum timed calls per configuration")
    i.add_argument("--min-seconds", type=float, default=1.0, help="minimum timing per configuration")
    i.add_argument("--markdown", type=Path, default=None, help="also write the table as markdown here")

    p = _command(bsub, "planner", "the planner benches (criterion) as a markdown table", _run_bench_planner)
    p.add_argument("--criterion", type=Path, default=paths.criterion() / "planner",
                   help="criterion results of the planner benches")
    p.add_argument("--markdown", type=Path, default=None, help="also write the table here")

    y = _command(bsub, "python", "per-step planning time seen from Python vs the Rust planner's own and criterion's",
                 _run_bench_python)
    y.add_argument("--reps", type=int, default=30, help="timed calls per configuration")
    y.add_argument("--ns", type=int, nargs="+", default=[2, 4, 8, 16], help="agent counts (ego included)")
    y.add_argument("--predictors", nargs="+", default=["teacher", "student", "constant_velocity"],
                   help="planning predictors timed")
    y.add_argument("--criterion", type=Path, default=paths.criterion(), help="criterion results")

    q = _command(bsub, "python-predictor", "cost per predictor call of a predictor written in Python "
                 "(numpy, PyTorch) vs the built-in ones, one thread (docs/python_predictor.md)",
                 _run_bench_python_predictor)
    q.add_argument("--seeds", type=int, default=2, help="target-lane seeds per shipped scene")
    q.add_argument("--torch-plans", type=int, default=8, help="MPC calls of the two student rows")
    q.add_argument("--markdown", type=Path, default=None, help="also write the table here")

    from nudge_train.experiments.latency_config import N_EDGES, WORLDS, LatencyConfig

    d = LatencyConfig(scenes=Path())
    t = _command(bsub, "latency", "p50/p90/p99/max of the planning step over closed-loop runs on a split's scenes "
                 "(one thread), per predictor and vehicle count, with step statuses: docs/results/latency.md",
                 _run_bench_latency)
    t.add_argument("--split", choices=SPLITS, default="test", help="the split whose scenes run")
    t.add_argument("--scenes", type=Path, default=None,
                   help="folder of scenario files (default data/processed/scenes/<split>)")
    t.add_argument("--n", type=int, default=d.n, help="scenes drawn (seeded, as in closed-loop)")
    t.add_argument("--seed", type=int, default=d.seed, help="seed of the scene draw and of the scene seeds")
    t.add_argument("--runs", type=int, default=d.runs, help="runs (target-lane seeds) per scene")
    t.add_argument("--predictors", nargs="+", default=list(d.predictors),
                   help="planning predictors (teacher, student, constant_velocity or weights files)")
    t.add_argument("--world", choices=WORLDS, default=d.world, help="how the other vehicles move")
    t.add_argument("--budget-ms", type=float, default=None,
                   help="also run every predictor with this work budget per call (PlannerSettings.budget_s, ms) "
                        "on the same runs, and count the steps above it + 1 ms")
    t.add_argument("--teacher-n", type=int, default=None,
                   help="run the teacher planner on a seeded subset of this many scenes (default: all)")
    t.add_argument("--n-edges", type=int, nargs="+", default=list(N_EDGES),
                   help="upper bounds (inclusive) of the vehicle-count buckets")
    t.add_argument("--chunk", type=int, default=d.chunk, help="scenes per chunk (every arm runs a chunk in turn)")
    t.add_argument("--horizons", type=int, nargs="+", default=[],
                   help="run every predictor at each of these planning horizons (steps), side by side")
    t.add_argument("--out", type=Path, default=_doc(paths.results() / "latency.md"),
                   help="the report (its section of this budget is replaced, the rest kept)")
    t.add_argument("--no-progress", action="store_true", help="no progress lines")


def _run_bench_inference(a: argparse.Namespace) -> int:
    from nudge_train.experiments.bench_inference import run

    try:
        return run(repo_root=a.repo_root, criterion_dir=a.criterion_dir, models=a.models, ns=a.ns,
                   batch32=a.batch32, warmup=a.warmup, repeats=a.repeats, min_seconds=a.min_seconds,
                   markdown=a.markdown)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


def _run_bench_planner(a: argparse.Namespace) -> int:
    from nudge_train.experiments.bench_planner import run

    return run(criterion=a.criterion, markdown=a.markdown)


def _run_bench_python(a: argparse.Namespace) -> int:
    from nudge_train.experiments.bench_python import run

    return run(reps=a.reps, ns=a.ns, predictors=a.predictors, criterion=a.criterion)


def _run_bench_python_predictor(a: argparse.Namespace) -> int:
    from nudge_train.experiments.bench_python_predictor import run

    return run(seeds=a.seeds, torch_plans=a.torch_plans, markdown=a.markdown)


def _run_bench_latency(a: argparse.Namespace) -> int:
    from nudge_train.experiments.bench_latency import LatencyConfig, command_line, run

    cfg = LatencyConfig(scenes=a.scenes or paths.scenes(a.split), n=a.n, seed=a.seed, runs=a.runs,
                        predictors=tuple(a.predictors), world=a.world, budget_ms=a.budget_ms, teacher_n=a.teacher_n,
                        n_edges=tuple(a.n_edges), chunk=a.chunk, progress=not a.no_progress,
                        horizons=tuple(a.horizons))
    try:
        cfg.validate()
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    argv = sys.argv[3:] if sys.argv[1:3] == ["bench", "latency"] else []
    return run(cfg, a.out, command_line(argv))


def _add_goldens(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "goldens", "write (or --check) the predictor golden files and the bench scenes", _run_goldens)
    p.add_argument("--repo-root", type=Path, default=paths.repo(), help="repository root")
    p.add_argument("--trained", action="store_true", help="also write cases against trained assets/models/*")
    p.add_argument("--ship-random", action="store_true", help="also write random assets/models/{teacher,student}")
    p.add_argument("--check", action="store_true", help="regenerate into a temp dir and compare bit-exactly")


def _run_goldens(a: argparse.Namespace) -> int:
    from nudge_train.testing.goldens import run

    return run(repo_root=a.repo_root, trained=a.trained, ship_random=a.ship_random, check_only=a.check)


def _add_figures(sub: argparse._SubParsersAction) -> None:
    figures = sub.add_parser("figures", help="figures (light: numpy + matplotlib)", description="figures")
    fsub = _subcommands(figures, "figures_cmd")

    r = _command(fsub, "runs", "draw closed-loop runs written by `nudge simulate --out DIR` as one PNG",
                 _run_figures_runs)
    r.add_argument("records_dir", type=Path, help="directory with records.json")
    r.add_argument("--scenes", type=Path, default=paths.shipped_scenes(), help="folder of the runs' scenario files")
    r.add_argument("--png", type=Path, default=None, help="output (default RECORDS_DIR/runs.png)")
    r.add_argument("--max-runs", type=int, default=6, help="runs drawn (the first ones)")

    c = _command(fsub, "curves", "draw the training curves (metrics.jsonl) of training runs as one PNG",
                 _run_figures_curves)
    c.add_argument("runs", nargs="+", metavar="NAME=DIR", help="a label and the run's out_dir")
    c.add_argument("--png", type=Path, required=True, help="output")
    c.add_argument("--title", default="training curves", help="figure title")
    c.add_argument("--loss-label", default="train loss", help="y label of the loss panel")
    c.add_argument("--val-label", default="validation metric (m)", help="y label of the validation panel")


def _run_figures_runs(a: argparse.Namespace) -> int:
    from nudge_train.experiments.plots import plot_runs

    return plot_runs(records_dir=a.records_dir, scenes=a.scenes, png=a.png, max_runs=a.max_runs)


def _run_figures_curves(a: argparse.Namespace) -> int:
    from nudge_train.experiments.plots import plot_curves

    runs: dict[str, Path] = {}
    for item in a.runs:
        name, sep, out = item.partition("=")
        if not sep or not name or not out:
            print(f"error: {item!r}: expected NAME=DIR", file=sys.stderr)
            return 2
        runs[name] = Path(out)
    plot_curves(runs, a.png, a.title, a.loss_label, a.val_label)
    print(f"wrote {a.png}")
    return 0


# ---- IDM world parameters ------------------------------------------------------------------------
def _add_idm(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "idm", "IDM fitted to real NGSIM car-following, the real cut-ins and the IDM world's "
                 "intrusion rule (assets/worlds/idm.json, cutins.json, docs/results/idm_fit.md)", _run_idm)
    p.add_argument("stage", choices=("fit", "cutins", "report", "all"), help="what to run")
    p.add_argument("--data-root", type=Path, default=paths.ngsim(), help="raw NGSIM material")
    p.add_argument("--runs", type=Path, default=paths.runs() / "idm", help="intermediate results (resumable fits)")
    p.add_argument("--assets", type=Path, default=paths.assets() / "worlds", help="where idm.json and cutins.json go")
    p.add_argument("--doc", type=Path, default=_doc(paths.results() / "idm_fit.md"), help="the report")
    p.add_argument("--figures", type=Path, default=_doc(paths.figures()), help="figure folder")
    p.add_argument("--seed", type=int, default=0, help="seed of the fits and of the rule search")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def _run_idm(a: argparse.Namespace) -> int:
    from nudge_train.idm.pipeline import run_stage

    return run_stage(a.stage, data_root=a.data_root, runs=a.runs, assets=a.assets, doc=a.doc,
                     figures=a.figures, seed=a.seed, progress=not a.no_progress)


# ---- entry point -------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    """The ``nudge-train`` parser; every subcommand's namespace carries its handler as ``run``."""
    parser = argparse.ArgumentParser(
        prog="nudge-train",
        description="nudge's data pipeline, training, experiments, benches, golden files and figures.",
        epilog="Default paths: the repository of this checkout; NUDGE_REPO, NUDGE_ASSETS and NUDGE_NGSIM "
               "override them.",
    )
    sub = _subcommands(parser, "cmd")
    _add_data(sub)
    _add_train(sub)
    _add_teacher(sub)
    _add_student(sub)
    _add_student_react(sub)
    _add_student_report(sub)
    _add_reaction(sub)
    _add_horizon(sub)
    _add_distill(sub)
    _add_closed_loop(sub)
    _add_slow_plans(sub)
    _add_group_cv(sub)
    _add_paper(sub)
    _add_interaction(sub)
    _add_bench(sub)
    _add_goldens(sub)
    _add_figures(sub)
    _add_idm(sub)
    _add_commonroad(sub)
    _add_replay_extrapolation(sub)
    _add_human_lane_changes(sub)
    return parser


# ---- human lane changes -------------------------------------------------------------------------
def _add_human_lane_changes(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "human-lane-changes", "every lane change in the real US-101 tracks (smoothed, by a documented "
                 "rule): duration, peak lateral acceleration, jerk and yaw rate per speed band and split, the human "
                 "reference of the planner's comfort limits (report, JSON summary, events CSV, figure)",
                 _run_human_lane_changes)
    p.add_argument("--data-root", type=Path, default=paths.ngsim(), help="raw NGSIM material")
    p.add_argument("--out", type=Path, default=paths.runs() / "human_lane_changes",
                   help="folder of the report, summary, events and figure (ignored with --publish)")
    p.add_argument("--publish", action="store_true",
                   help="write the tracked files instead: docs/results/human_lane_changes.{md,json,csv} and "
                        "docs/figures/human_lane_changes.png")
    p.add_argument("--seed", type=int, default=0, help="seed of the split assignment")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def _run_human_lane_changes(a: argparse.Namespace) -> int:
    from nudge_train.experiments.human_lane_changes import GROUPS, in_group, run

    stem = "human_lane_changes"
    if a.publish:
        doc, png = paths.results() / f"{stem}.md", paths.figures() / f"{stem}.png"
    else:
        doc, png = a.out / f"{stem}.md", a.out / f"{stem}.png"
    command = "nudge-train human-lane-changes" + (" --publish" if a.publish else "")
    st = run(a.data_root, doc, doc.with_suffix(".json"), doc.with_suffix(".csv"), png, command, seed=a.seed,
             progress=not a.no_progress)
    counts = ", ".join(f"{g} {sum(in_group(e, g) for e in st.events)}" for g in GROUPS)
    print(f"wrote {doc} (+ .json, .csv) and {png}: lane changes {counts}")
    return 0


# ---- log replay past a log's end ----------------------------------------------------------------
def _add_replay_extrapolation(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "replay-extrapolation", "fit the log-replay world's sideways decay past a log's end to "
                 "real tracks (training scenes) and report it on the validation and test scenes; exit 1 when "
                 "the shipped default is not the fitted value", _run_replay_extrapolation)
    p.add_argument("--scenes-root", type=Path, default=paths.scenes("train").parent,
                   help="folder holding the train, val and test scene folders")
    p.add_argument("--out", type=Path, default=_doc(paths.results() / "replay_extrapolation.md"), help="the report")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def _run_replay_extrapolation(a: argparse.Namespace) -> int:
    from nudge_train.experiments.replay_extrapolation import run

    return run(a.scenes_root, a.out, progress=not a.no_progress)


# ---- CommonRoad ---------------------------------------------------------------------------------
def _add_commonroad(sub: argparse._SubParsersAction) -> None:
    p = _command(sub, "commonroad", "plan the shipped scenes in their CommonRoad files with the nudge command and "
                 "check the solutions with commonroad-drivability-checker (the commonroad extra)", _commonroad)
    p.add_argument("--nudge", type=Path, default=None,
                   help="the nudge command (default: the checkout's target/release/nudge, else `nudge` on PATH)")
    p.add_argument("--out", type=Path, default=Path("runs/commonroad"), help="runs and solutions")
    p.add_argument("--markdown", type=Path, default=None, help="write the table here")
    p.add_argument("--problems-only", action="store_true",
                   help="only plan and check every planning problem of the 62 US-101 files (print the section)")


def _commonroad(args: argparse.Namespace) -> int:
    from nudge_train.experiments.commonroad_check import all_problems, problems_markdown, run

    if args.problems_only:
        print(problems_markdown(all_problems(args.nudge, args.out / "problems"),
                                "nudge-train commonroad --problems-only"))
        return 0
    print(run(args.nudge, args.out, args.markdown))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Runs ``nudge-train`` with ``argv`` (default: the command line); returns the exit status
    (2 for a typed error of :mod:`nudge_train.errors` — bad data, a damaged artefact, a malformed
    config, a training failure — printed as ``error: ...`` without a traceback; 130 for Ctrl-C,
    one line on stderr)."""
    args = build_parser().parse_args(argv)
    _redirect_tracked_defaults(args)
    from nudge_train.errors import NudgeTrainError

    try:
        return args.run(args)
    except NudgeTrainError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted (a resumable command such as distill resumes from its last complete shard)",
              file=sys.stderr)
        return 130

