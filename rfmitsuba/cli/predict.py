"""``rfmitsuba predict RUN --positions FILE --out DIR``: a trained run's PAS at positions of your choice."""
from __future__ import annotations

from ._values import positive_int


def register(sub) -> None:
    p = sub.add_parser("predict", help="render a trained run at the positions in a file (writes DIR/pas.npy, "
                                       "DIR/spectrum/*.png, DIR/positions.csv)")
    p.add_argument("run", help="run folder written by `rfmitsuba train`")
    p.add_argument("--positions", required=True,
                   help="the moving device's positions [m]: .npy [K, 3], or text with x y z per line "
                        "read as a NeRF2 tx_pos.csv (commas or spaces; a header row may name the columns)")
    p.add_argument("--out", required=True, help="new or empty folder for the prediction")
    p.add_argument("--anchored", action="store_true",
                   help="the neighbour-anchored prediction with the (k, alpha) `rfmitsuba eval` chose on validation")
    p.add_argument("--no-room-check", dest="check_room", action="store_false",
                   help="render positions outside the known room (or inside its furniture) too")
    p.add_argument("--batch", type=positive_int, default=8, help="views per render call")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..core.folder_lock import writer
    from ..eval.predict import new_folder, predict_run, read_positions, write_prediction

    new_folder(args.out)                      # before rendering: a full folder is refused at once
    with writer(args.out, what="predict"):    # one writer: a second predict into it is refused
        new_folder(args.out)                  # the first writer may have finished meanwhile
        res = predict_run(args.run, read_positions(args.positions), anchor=args.anchored, batch=args.batch,
                          check_room=args.check_room)
        out = write_prediction(args.out, res)
    print(f"{len(res['positions'])} PAS ({res['how']}) of {res['run']} written to {out}")
    return 0
