"""``rfmitsuba generate``: simulate a PAS dataset with Sionna RT (resumable)."""
from __future__ import annotations

import json
import time

from ..core import cluster
from ._values import nonnegative_int, positive_int


def register(sub) -> None:
    p = sub.add_parser("generate", help="simulate a PAS dataset of a scene (moving RX or moving TX); resumable",
                       description="Simulate a dataset: empty room + one state per person position, one chunk per "
                                   "state. Re-running the same command into the same --out continues where it "
                                   "stopped; the result is bit-identical to an uninterrupted run.")
    p.add_argument("scene", help="built-in scene name (bedroom, living_room, dining_room, large_room) or an XML file")
    p.add_argument("--task", choices=["rx", "tx"], default="rx",
                   help="rx: the 4x4 array moves, TX fixed in a corner; tx: the TX moves, array fixed (default rx)")
    p.add_argument("--out", required=True, help="dataset folder (created, or resumed if it holds this configuration)")
    p.add_argument("--positions", type=int, default=None, help="antenna positions (default 900; 36 with --quick)")
    p.add_argument("--person-positions", type=int, default=None,
                   help="person positions along a 60 s walk (default 35; 4 with --quick)")
    p.add_argument("--people", type=positive_int, default=1,
                   help="people walking at once, each on a walk of its own that never comes within 0.1 m of "
                        "another's body (default 1)")
    p.add_argument("--material", choices=["tissue", "metal", "concrete"], default="tissue",
                   help="material of the person-shaped perturber (default tissue)")
    p.add_argument("--seed", type=int, default=0, help="seed of positions, walk and split (default 0)")
    p.add_argument("--quick", action="store_true", help="a small dataset in well under a minute (36 x 5 states)")
    p.add_argument("--diffuse", action="store_true", help="add diffuse reflection (seed-dependent, slow)")
    p.add_argument("--diffraction", action="store_true", help="add edge diffraction")
    p.add_argument("--samples", type=float, default=None,
                   help="ray samples per source (default 1e5; 3e5 for rooms over 50 m^2; 2e4 with --quick)")
    p.add_argument("--max-depth", type=int, default=3, help="maximum interactions per path (default 3)")
    p.add_argument("--solver-seed", type=int, default=42, help="seed of the ray tracer (default 42)")
    p.add_argument("--threads", type=nonnegative_int, default=1,
                   help="threads of the ray tracer; 1 (default) is bit-reproducible, 0 = all cores")
    p.add_argument("--frequency", type=float, default=2.4e9, help="carrier in Hz (default 2.4e9)")
    p.add_argument("--array", choices=["synthetic", "exact"], default="synthetic",
                   help="synthetic (default): one trace per array position, element phases by the plane-wave "
                        "rule; exact: each of the 16 elements traced as its own antenna (no plane-wave "
                        "approximation; 16x the receivers, for a subset of positions, at most 200)")
    p.add_argument("--repair", action="store_true", help="re-simulate chunks that fail the sha256 check")
    cluster.add_cli_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..core.errors import ConfigError
    from ..data import store as D
    from ..sim import generate as gen
    from ..sim.geometry import RoomGeometry
    from ..sim.simulate import SolverConfig

    if args.positions is not None and args.positions < 1:
        raise ConfigError(f"--positions must be >= 1, got {args.positions}")
    if args.person_positions is not None and args.person_positions < 0:
        raise ConfigError(f"--person-positions must be >= 0, got {args.person_positions}")
    if args.samples is not None and (args.samples < 1 or args.samples != int(args.samples)):
        raise ConfigError(f"--samples must be a positive integer, got {args.samples}")
    xml = D.resolve_scene(args.scene)
    base = gen.default_solver(RoomGeometry.from_xml(xml), quick=args.quick)
    solver = SolverConfig(samples_per_src=int(args.samples) if args.samples else base.samples_per_src,
                          max_depth=args.max_depth, diffuse_reflection=args.diffuse, diffraction=args.diffraction,
                          seed=args.solver_seed, threads=args.threads)
    cfg = gen.quick_config(str(args.scene)) if args.quick else gen.GenerateConfig(scene=str(args.scene))
    cfg.task = args.task
    cfg.material = args.material
    cfg.seed = args.seed
    cfg.frequency_hz = args.frequency
    cfg.solver = solver
    cfg.array = args.array
    cfg.people = args.people
    if args.positions is not None:
        cfg.positions = args.positions
    if args.person_positions is not None:
        cfg.person_positions = args.person_positions
    t = time.perf_counter()
    ds = gen.generate(args.out, cfg, repair=args.repair, cluster=cluster.from_cli(args))
    wall = time.perf_counter() - t
    runs = json.loads((ds.path / "timing.json").read_text())
    last = runs[-1]
    n_pas = last["states"] * ds.num_antennas
    print(f"{ds.path}: {ds.num_antennas} positions x {ds.num_states} states ({ds.task} task, "
          f"{cfg.array} array); "
          f"simulated {last['states']} state(s) in {wall:.1f} s"
          + (f", {n_pas / wall:.1f} PAS/s, {100 * last['outside_solver_share']:.1f}% outside the ray tracer"
             if last["states"] else " (nothing to do)"))
    return 0
