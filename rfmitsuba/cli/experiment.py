"""``rfmitsuba experiment motivation|parsimony|splits DATASET --out DIR``: multi-run Stage-1 tables;
``rfmitsuba experiment truth --scene S --positions N --out DIR``: the ground truth's own error bar."""
from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("experiment", help="motivation table (SSIM vs positions), parsimony curve (SSIM vs "
                                          "Gaussians), split sensitivity (every field and floor under the "
                                          "dataset's split and the block split) or truth uncertainty (synthetic "
                                          "array vs exact tracing)")
    p.add_argument("kind", choices=["motivation", "parsimony", "splits", "truth"])
    p.add_argument("dataset", nargs="?", default=None, help="dataset folder (motivation, parsimony, splits)")
    p.add_argument("--out", required=True, help="folder for the runs (or datasets) and the table")
    p.add_argument("--config", default=None, help="TrainConfig TOML for every run")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    p.add_argument("--counts", default=None, help="comma-separated positions (motivation), caps (parsimony, splat) "
                                                   "or scatterers (parsimony, model=coherent_gaussians)")
    p.add_argument("--fields", default=None,
                   help="splits: comma-separated field kinds (default coherent_gaussians,splat; 'auto' is what "
                        "`rfmitsuba train` picks)")
    p.add_argument("--seeds", default="0,1,2", help="splits: comma-separated training seeds (default 0,1,2)")
    p.add_argument("--tag", default="", help="splits: a name for this call's settings (e.g. long with "
                                             "--set iterations=12000): its rows and run folders are <field>-<tag>")
    p.add_argument("--quick", action="store_true", help="quick training config and small counts")
    t = p.add_argument_group("truth", "generate the same positions with the synthetic and the exact array "
                                      "(rfmitsuba.experiments.truth) and compare channels and PAS")
    t.add_argument("--scene", default="bedroom", help="truth: built-in scene or XML file (default bedroom)")
    t.add_argument("--task", choices=["rx", "tx"], default="rx", help="truth: moving RX or moving TX (default rx)")
    t.add_argument("--positions", type=int, default=48, help="truth: antenna positions (default 48, at most 200)")
    t.add_argument("--person-positions", type=int, default=0,
                   help="truth: person positions along the walk (default 0: empty room)")
    t.add_argument("--seed", type=int, default=0, help="truth: seed of positions and walk (default 0)")
    t.add_argument("--samples", type=int, default=None, help="truth: ray samples per source (default: the room's)")
    t.add_argument("--no-repeat", action="store_true",
                   help="truth: skip tracing the exact truth again with the next solver seed (the noise floor)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)


def run(args) -> int:
    """One writer per experiment folder: a second experiment into ``--out`` is refused, naming the
    first one's pid; a folder this call created is removed when it fails before writing anything."""
    from ..core.folder_lock import writer

    with writer(args.out, what="experiment"):
        return _run(args)


def _run(args) -> int:
    from pathlib import Path

    from ..core.errors import ConfigError

    if args.kind == "truth":
        from ..experiments import truth as T

        if args.dataset is not None:
            raise ConfigError("experiment truth generates its own datasets: give --scene, not a dataset folder")
        if args.positions < 1 or args.person_positions < 0:
            raise ConfigError(f"need --positions >= 1 and --person-positions >= 0, got {args.positions}, "
                              f"{args.person_positions}")
        cfg = T.TruthConfig(scene=args.scene, task=args.task, positions=args.positions,
                            person_positions=args.person_positions, seed=args.seed, samples=args.samples,
                            repeat=not args.no_repeat)
        T.truth_uncertainty(args.out, cfg, quiet=args.quiet)
        print((Path(args.out) / "table.md").read_text().split("\nPer PAS")[0])
        return 0
    if args.dataset is None:
        raise ConfigError(f"experiment {args.kind} needs a dataset folder")
    from ..experiments import tables as E
    from ._values import whole_numbers
    from .train import build_config

    cfg = build_config(args)
    if args.kind in ("motivation", "parsimony") and cfg.model == "auto" and not _names_model(args):
        import dataclasses   # these tables compare one kind across their rows: the splat field unless told

        cfg = dataclasses.replace(cfg, model="splat")
    counts = tuple(whole_numbers(args.counts, option="--counts", least=1, example="20,45,90")) if args.counts else None
    if args.kind == "splits":
        fields = tuple(f.strip() for f in args.fields.split(",") if f.strip()) if args.fields else E.SENSITIVITY_FIELDS
        seeds = tuple(whole_numbers(args.seeds, option="--seeds"))
        E.split_sensitivity(args.dataset, args.out, fields=fields, seeds=seeds, cfg=cfg, tag=args.tag,
                            quiet=args.quiet)
    elif args.kind == "motivation":
        counts = counts or (E.QUICK_MOTIVATION_COUNTS if args.quick else E.MOTIVATION_COUNTS)
        E.motivation_table(args.dataset, args.out, counts=counts, cfg=cfg, quiet=args.quiet)
    else:
        if cfg.model == "coherent_gaussians":  # counts are numbers of scatterers
            counts = counts or ((0, 8, 32) if args.quick else (0, 8, 16, 32, 64, 96))
        counts = counts or ((300, 600, 1200, 2400) if args.quick else (500, 1000, 2000, 4000, 8000))
        E.parsimony_curve(args.dataset, args.out, caps=counts, cfg=cfg, quiet=args.quiet)

    print((Path(args.out) / "table.md").read_text())
    return 0


def _names_model(args) -> bool:
    """Whether the command line or its --config file sets ``model``."""
    import tomllib

    if any(s.split("=", 1)[0].strip() == "model" for s in args.set):
        return True
    if args.config:
        try:
            return "model" in tomllib.loads(open(args.config, encoding="utf-8").read())
        except (OSError, tomllib.TOMLDecodeError):
            return False
    return False
