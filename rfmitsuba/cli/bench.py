"""``rfmitsuba bench splat``: time the splatting kernels against PyTorch-CPU."""
from __future__ import annotations

import json
from pathlib import Path

from ..core.errors import ConfigError


def register(sub) -> None:
    p = sub.add_parser("bench", help="benchmark kernels (splat: Dr.Jit vs PyTorch-CPU)")
    p.add_argument("what", choices=["splat"], help="which kernels to benchmark")
    p.add_argument("--quick", action="store_true",
                   help="tiny N, one repetition, 18x72 images (a smoke test, not a measurement)")
    p.add_argument("--sizes", default=None,
                   help="comma-separated Gaussian counts (default 2000,10000,50000)")
    p.add_argument("--repeats", type=int, default=None, help="timed repetitions per figure (default 5)")
    p.add_argument("--views", type=int, default=1, help="PAS per call (a batch of receiver positions)")
    p.add_argument("--no-torch", action="store_true", help="skip the PyTorch comparison")
    p.add_argument("--json", type=Path, default=None, help="also write the results to this JSON file")
    p.set_defaults(func=run)


def run(args) -> int:
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
        sizes = bench.QUICK_SIZES if args.quick else bench.SIZES
    repeats = args.repeats if args.repeats is not None else (1 if args.quick else 5)
    if repeats < 1:
        raise ConfigError(f"--repeats must be >= 1, got {repeats}")
    if args.views < 1:
        raise ConfigError(f"--views must be >= 1, got {args.views}")
    height, width = (18, 72) if args.quick else (90, 360)
    with bar(total=len(sizes), desc="bench splat", unit="N") as pb:
        result = bench.run(sizes=sizes, repeats=repeats, height=height, width=width,
                           torch=not args.no_torch, progress=lambda n: pb.update(1),
                           compile_n=300 if args.quick else 2000, views=args.views)
    print(bench.format_report(result))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2))
    return 0
