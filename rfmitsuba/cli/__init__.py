"""The ``rfmitsuba`` command line.

Each sub-command lives in its own module of this package and exposes
``register(subparsers)``, which adds an ``argparse`` parser whose ``func``
default runs the command and returns an exit code. :data:`COMMANDS` lists the
modules in the order ``rfmitsuba --help`` shows them.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from ..core.errors import RfmError

#: Sub-command modules, in help order.
COMMANDS = ["info", "generate", "nerf2like", "show", "invert", "train", "eval", "predict", "experiment", "compare", "reproduce", "demo", "bench"]


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="rfmitsuba",
        description="RF radiance-field reconstruction with differentiable Gaussian splatting.",
    )
    parser.add_argument("--variant", default=None,
                        help="Mitsuba/Dr.Jit variant: llvm, cuda or a full variant name (default: cuda if usable, else llvm)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code (2 for bad input, with the reason on stderr)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from ..core.memory import keep_freed_memory

    keep_freed_memory()
    try:
        if args.variant:
            from ..core import backend

            backend.set_variant(args.variant)
        return int(args.func(args) or 0)
    except RfmError as e:
        print(f"rfmitsuba {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rfmitsuba {args.command}: interrupted; finished work is kept, run the same command to resume",
              file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
