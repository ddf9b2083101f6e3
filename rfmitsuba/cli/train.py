"""``rfmitsuba train DATASET --out RUN``: train a Stage-1 background Gaussian field."""
from __future__ import annotations

from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("train", help="train a background Gaussian field on a dataset (resumes an interrupted run)")
    p.add_argument("dataset", help="dataset folder (rfmitsuba generate), NeRF2 spectrum folder or One Walk folder")
    p.add_argument("--out", required=True, help="run folder (created; an interrupted run of the same config resumes)")
    p.add_argument("--config", default=None, help="TrainConfig TOML file")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. --set iterations=2000 --set splat.num_gaussians=4000")
    p.add_argument("--quick", action="store_true", help="small fast run (300 steps, half resolution)")
    p.add_argument("--model", default=None,
                   help="the field: 'auto' (the default, unless --config names one: train each candidate field for a "
                        "quarter of the budget, keep the best by validation SSIM), 'coherent_gaussians', 'splat', "
                        "'coherent' or 'gaussian_process'; same as --set model=...")
    p.add_argument("--split", choices=["dataset", "block", "random"], default=None,
                   help="test positions: the dataset's own split (a NeRF2 folder's published index files), "
                        "'block' (the 20%% of positions with the largest x, a held-out slab) or 'random' "
                        "(seeded 80/20); same as --set split=...")
    p.add_argument("--dry-run", action="store_true",
                   help="print every 'auto' the run would decide, with the reason for each (RUN/resolved.toml of a "
                        "real run), and exit: nothing is trained or written")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def build_config(args):
    """The TrainConfig of the command line: file, then --quick, then --model, --set and --split.

    Without ``--model`` the model is the config's (``"auto"`` unless a ``--config`` file names one:
    the same default as :class:`~rfmitsuba.train.config.TrainConfig` in Python)."""
    from ..core import config as C
    from ..train.config import TrainConfig, quick_config

    cfg = C.load(TrainConfig, args.config) if args.config else TrainConfig()
    if args.quick:
        cfg = quick_config(cfg)
    model = getattr(args, "model", None)
    sets = ([f'model="{model}"'] if model else []) + list(args.set)
    sets += [f'split="{args.split}"'] if getattr(args, "split", None) else []
    return C.override(cfg, sets) if sets else cfg


def run(args) -> int:
    from ..train.trainer import dry_run, train

    cfg = build_config(args)
    if args.dry_run:
        print(dry_run(args.dataset, cfg=cfg), end="")
        return 0
    s = train(args.dataset, args.out, cfg=cfg, quiet=args.quiet)
    print(f"run {Path(args.out)}: {s['steps']} steps in {s['train_time_s']:.1f} s, {s['num_gaussians']} "
          f"Gaussians, {s['num_parameters']} parameters, {validation_text(s, cfg)}")
    print(f"next: rfmitsuba eval {args.out}")
    return 0


def validation_text(summary: dict, cfg) -> str:
    """"validation SSIM 0.735", or why there is none (too few training positions to hold any
    back at ``val_fraction``)."""
    import math

    v = summary.get("val_ssim")
    if isinstance(v, (int, float)) and math.isfinite(v):
        return f"validation SSIM {v:.3f}"
    return (f"no validation SSIM: no training position was held back for validation (val_fraction = "
            f"{cfg.val_fraction:g} of the training positions, at least one is always fitted); the run kept its last "
            "step. Use more positions, or --set val_fraction=0.2, to have one")
