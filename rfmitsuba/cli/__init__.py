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
COMMANDS = ["info", "generate", "nerf2like", "export", "show", "invert", "train", "eval", "predict", "experiment", "compare", "reproduce", "demo", "bench"]


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
    except BaseException as e:                     # noqa: BLE001 - named below, or raised again
        code, message = _named_fault(e)
        if code is None:
            raise
        print(f"rfmitsuba {args.command}: {message}", file=sys.stderr)
        return code


def _cause_chain(e: BaseException):
    """``e`` and the exceptions it was raised from (``__cause__``, else ``__context__``): Dr.Jit's
    loops re-raise a Ctrl-C or an OSError inside them as a RuntimeError of their own."""
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        yield e
        e = e.__cause__ or e.__context__


def _named_fault(e: BaseException) -> tuple[int | None, str]:
    """(exit code, one-line message) for a fault a user can cause, or (None, "") for a bug.

    Ctrl-C: 130, "interrupted; finished work is kept"; a file-system error (disk full, read-only,
    a file where a folder belongs, permission): 1, naming the path and the cause; out of memory:
    1, with the size asked for."""
    import errno

    chain = list(_cause_chain(e))
    if any(isinstance(x, KeyboardInterrupt) for x in chain):
        return 130, "interrupted; finished work is kept, run the same command to resume"
    mem = next((x for x in chain if isinstance(x, MemoryError)), None)
    if mem is not None:
        what = str(mem) or "an allocation failed"
        return 1, (f"error: out of memory ({what}); ask for fewer positions, states or views per call "
                   "(--positions, --human-positions, --batch)")
    ose = next((x for x in chain if isinstance(x, OSError) and (x.filename or x.errno)), None)
    if ose is not None:
        path = ose.filename if ose.filename is not None else "(no path)"
        cause = ose.strerror or errno.errorcode.get(ose.errno or 0, str(ose))
        hint = {errno.ENOSPC: "; free space or write elsewhere (--out), finished work is kept",
                errno.EROFS: "; write elsewhere (--out)", errno.EACCES: "; check the permissions or write elsewhere",
                errno.ENOTDIR: "; a file stands where a folder belongs",
                errno.EEXIST: "; a file stands where a folder belongs"}.get(ose.errno, "")
        return 1, f"error: {path}: {cause}{hint}"
    return None, ""


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
