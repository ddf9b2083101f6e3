"""``rfmitsuba reproduce [--quick] --out DIR``: the paper's tables on our data, resumable."""
from __future__ import annotations

import sys
from pathlib import Path

from ..core import cluster


def register(sub) -> None:
    p = sub.add_parser("reproduce", help="generate data, train every method, write the paper's tables (resumable)")
    p.add_argument("--out", required=True,
                   help="output folder (report.md, jobs/, data/); a killed run resumes, and without --config, --size, "
                        "--quick, --tables or --set an existing folder runs, plans or reports its own selection "
                        "(OUT/experiment.toml)")
    p.add_argument("--quick", action="store_true", help="the quick size (minutes on 2 cores)")
    p.add_argument("--size", choices=["tiny", "quick", "medium", "full"], default=None,  # sizes.PAPER_SIZES
                   help="experiment size (default full; --quick = quick; tiny = synthetic data, seconds; medium = "
                        "300 positions, the data-scarce table on 2 cores)")
    p.add_argument("--tables", default=None, metavar="KEY[,KEY]",
                   help="run these tables only (comma-separated, e.g. data_scarce; default: the size's tables, "
                        "every one but data_scarce)")
    p.add_argument("--config", default=None, help="ExperimentConfig TOML file (instead of a size)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. --set seeds=[0,1,2,3] --set train.stage2_iterations=500")
    p.add_argument("--data", default=None, help="dataset folder to reuse/generate into (default OUT/data)")
    p.add_argument("--reevaluate", action="store_true",
                   help="evaluate finished jobs again (after the evaluation changed); training is kept")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--plan", action="store_true",
                   help="run nothing: print the datasets and jobs still to do per table, with their wall time "
                        "estimated from finished jobs (rfmitsuba.experiments.plan); with --workers N also the wall time "
                        "on N workers; writes nothing")
    p.add_argument("--plan-from", action="append", default=[], metavar="DIR",
                   help="with --plan: also time the estimates by the finished jobs of this reproduction folder")
    p.add_argument("--report-only", action="store_true",
                   help="run nothing: write OUT/report.md from the jobs finished so far (the others show as '-'); "
                        "of OUT's own selection (OUT/experiment.toml) unless --config, --size, --tables or --set "
                        "choose another; safe beside a running reproduction")
    cluster.add_cli_options(p)
    p.set_defaults(func=run)


def selects(args) -> bool:
    """Whether the command line chooses an experiment (--config, --size, --quick, --tables or --set)."""
    return bool(args.config or args.size or args.quick or args.set or getattr(args, "tables", None))


def build_config(args):
    """The ExperimentConfig of the command line: --config file or size, then --set overrides; with
    none of them, the existing ``--out`` folder's own (its experiment.toml, as its latest run saved
    it), else the full size. The one place a bare ``--out`` is decided: running, ``--plan`` and
    ``--report-only`` all take the folder's selection, not the default size's tables."""
    from ..core import config as C
    from ..core.errors import ConfigError
    from ..experiments.sizes import ExperimentConfig, size_config

    if args.config and (args.quick or args.size):
        raise ConfigError("give either --config or --quick/--size, not both")
    saved = Path(args.out) / "experiment.toml"
    if not selects(args) and saved.is_file():
        print(f"{args.out}: its own selection ({saved}); give --size, --config, --tables or --set to choose another",
              file=sys.stderr)
        return C.load(ExperimentConfig, saved, saved=True)
    if args.config:
        cfg = C.load(ExperimentConfig, args.config)
    else:
        cfg = size_config(args.size or ("quick" if args.quick else "full"))
    sets = list(args.set)
    if getattr(args, "tables", None):
        sets.append("tables=" + repr([t.strip() for t in args.tables.split(",") if t.strip()]))
    return C.override(cfg, sets) if sets else cfg


def run(args) -> int:
    from ..experiments.reproduce import reproduce

    cfg = build_config(args)
    if args.plan:
        from ..experiments.plan import format_plan, plan

        workers = max(getattr(args, "workers", 0) or 0, 1)
        print(format_plan(plan(args.out, cfg, data_dir=args.data, reference=args.plan_from, workers=workers)))
        return 0
    if args.plan_from:
        from ..core.errors import ConfigError

        raise ConfigError("--plan-from goes with --plan")
    if args.report_only:
        from ..experiments.reproduce import report_finished

        path, done, total = report_finished(args.out, cfg if selects(args) else None)
        print(f"report of {done} of {total} jobs finished: {path}")
        return 0
    path = reproduce(args.out, cfg, data_dir=args.data, reevaluate=args.reevaluate, quiet=args.quiet,
                     cluster=cluster.from_cli(args))
    print(f"report: {path}")
    return 0
