"""``rfmitsuba bench [all|field|splat]``: time the kernels against references of the same math, in
one run: the coherent Gaussian field against its PyTorch twin, the Bartlett op against NumPy,
render time per PAS, Stage-1 steps per second (``field``), and the splatting kernels against
PyTorch-CPU (``splat``); ``all`` (the default) runs both, the splat part at 10k Gaussians."""
from __future__ import annotations

import json
from pathlib import Path

from ..core.errors import ConfigError


def register(sub) -> None:
    p = sub.add_parser("bench", help="benchmark kernels against references of the same math (ratios, one run)")
    p.add_argument("what", nargs="?", default="all", choices=["all", "field", "splat"],
                   help="field: coherent Gaussian field, Bartlett op, render per PAS, Stage-1 steps/s; "
                        "splat: splatting kernels vs PyTorch-CPU; all (default): both (splat at 10k Gaussians)")
    p.add_argument("--quick", action="store_true",
                   help="a smoke test, not a measurement: splat at tiny N, one repetition, 18x72 images; field with "
                        "16 scatterers, 3 repetitions, 30 Stage-1 steps")
    p.add_argument("--sizes", default=None,
                   help="splat: comma-separated Gaussian counts (default 2000,10000,50000; with 'all' 10000)")
    p.add_argument("--repeats", type=int, default=None, help="timed repetitions per figure, at least (default 5; a splat figure also runs for at least 1 s)")
    p.add_argument("--views", type=int, default=1, help="PAS per call (a batch of receiver positions)")
    p.add_argument("--no-torch", action="store_true", help="skip the PyTorch comparison")
    p.add_argument("--dataset", type=Path, default=None,
                   help="dataset of the Stage-1 timings (default: a NeRF2-like folder made once in the cache)")
    p.add_argument("--stage1-model", default="coherent_gaussians",
                   help="field: model of the Stage-1 timing (default coherent_gaussians)")
    p.add_argument("--stage1-config", type=Path, default=None,
                   help="field: training TOML of the Stage-1 timing instead of --stage1-model's defaults")
    p.add_argument("--no-stage1", action="store_true",
                   help="skip the Stage-1 timings (field: steps/s of the coherent field; splat: one splat step "
                        "with the networks' products on the host and as cooperative vectors)")
    p.add_argument("--json", type=Path, default=None, help="also write the results to this JSON file")
    p.set_defaults(func=run)


def run(args) -> int:
    results = {}
    if args.what in ("all", "field"):
        results["field"] = _field(args)
    if args.what in ("all", "splat"):
        results["splat"] = _splat(args, default_sizes=(10_000,) if args.what == "all" else None)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results if args.what == "all" else results[args.what], indent=2, default=str))
    return 0


def _field(args) -> dict:
    from ..experiments import bench_field

    if args.dataset is not None and not args.dataset.exists():
        raise ConfigError(f"--dataset {args.dataset} does not exist")
    if args.stage1_config is not None and not args.stage1_config.is_file():
        raise ConfigError(f"--stage1-config {args.stage1_config} is not a file")
    result = bench_field.run(quick=args.quick, dataset=args.dataset, stage1_model=args.stage1_model,
                             stage1_config=args.stage1_config, stage1=not args.no_stage1)
    print(bench_field.format_report(result))
    print()
    return result


def _splat(args, *, default_sizes: tuple | None) -> dict:
    from ..core.progress import bar
    from ..experiments import bench

    if args.sizes:
        try:
            sizes = tuple(int(s) for s in args.sizes.split(","))
        except ValueError:
            raise ConfigError(f"--sizes must be comma-separated integers, got {args.sizes!r}") from None
        if any(n <= 0 for n in sizes):
            raise ConfigError(f"--sizes must be positive, got {args.sizes!r}")
    else:
        sizes = bench.QUICK_SIZES if args.quick else (default_sizes or bench.SIZES)
    repeats = args.repeats if args.repeats is not None else (1 if args.quick else 5)
    if repeats < 1:
        raise ConfigError(f"--repeats must be >= 1, got {repeats}")
    if args.views < 1:
        raise ConfigError(f"--views must be >= 1, got {args.views}")
    height, width = (18, 72) if args.quick else (90, 360)
    with bar(total=len(sizes), desc="bench splat", unit="N") as pb:
        result = bench.run(sizes=sizes, repeats=repeats, height=height, width=width,
                           torch=not args.no_torch, progress=lambda n: pb.update(1),
                           compile_n=300 if args.quick else 2000, views=args.views,
                           min_time_s=0.0 if args.quick else bench.MIN_TIME_S)
    print(bench.format_report(result))
    if not args.no_stage1:
        dataset = None
        if args.dataset is not None:
            if not args.dataset.exists():
                raise ConfigError(f"--dataset {args.dataset} does not exist")
            dataset = str(args.dataset)
        from ..experiments import bench_field

        result["stage1_step"] = bench_field.measure_stage1_step(gaussians=2000 if args.quick else 10_000,
                                                                steps=14 if args.quick else 110, dataset=dataset)
        print(bench_field.format_stage1_step(result["stage1_step"]))
    return result
