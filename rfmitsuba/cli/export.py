"""``rfmitsuba export DATASET --format one-walk OUT``: write a dataset in another project's layout."""
from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("export", help="write a dataset in another layout: one-walk (OUT/static and OUT/dynamic, "
                                      "as the One Walk code reads them) or nerf2 (one state)")
    p.add_argument("dataset", help="dataset folder (rfmitsuba generate), NeRF2 folder or One Walk folder")
    p.add_argument("out", help="folder to write (new or empty)")
    p.add_argument("--format", required=True, choices=("one-walk", "nerf2"),
                   help="one-walk: OUT/static (the empty room: spectrum/, rx_info.csv, gateway_info.yml, index "
                        "files) and, with person states, OUT/dynamic (spectrums/, spectrum_info.csv, train / val / "
                        "test index files); nerf2: spectrum/, tx_pos.csv, gateway_info.yml, index files")
    p.add_argument("--state", type=int, default=None,
                   help="nerf2 only: which state to write (default 0, the empty room)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..core.errors import ConfigError
    from ..data import nerf2, one_walk
    from ..data.store import open_dataset

    ds = open_dataset(args.dataset)
    if args.format == "nerf2":
        out = nerf2.write(ds, args.out, state=args.state or 0)
        print(f"NeRF2 folder {out}: {ds.num_antennas} spectra of state {args.state or 0}")
        print(f"next: rfmitsuba train {out} --out RUN")
        return 0
    if args.state is not None:
        raise ConfigError("--state is for --format nerf2; --format one-walk writes every state")
    out = one_walk.write(ds, args.out)
    H = ds.num_states - 1
    print(f"One Walk static folder {out / 'static'}: {ds.num_antennas} spectra of the empty room")
    if H:
        print(f"One Walk dynamic folder {out / 'dynamic'}: {H * ds.num_antennas} spectra ({H} frames x "
              f"{ds.num_antennas} positions)")
        print(f"next: rfmitsuba compare {out} --out DIR   (or rfmitsuba train {out / 'static'} --out RUN)")
    else:
        print(f"next: rfmitsuba train {out / 'static'} --out RUN")
    return 0
