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
import warnings

from ..core.errors import RfmError
from ..core.interrupt import Terminated, sigterm_interrupts
from ..core.legacy_names import current_name

#: Sub-command modules, in help order.
COMMANDS = ["info", "generate", "nerf2like", "export", "show", "invert", "train", "eval", "predict", "locate", "experiment", "compare", "reproduce", "demo", "bench"]


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


def _renamed_flag(argv: list[str]) -> tuple[str, str] | None:
    """The first option in ``argv`` whose name holds a word that changed (``--human-positions``:
    :mod:`rfmitsuba.core.legacy_names`) and its new name, or None."""
    for a in argv:
        flag = a.split("=", 1)[0]
        if flag.startswith("--") and current_name(flag) != flag:
            return flag, current_name(flag)
    return None


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code (2 for bad input, with the reason on stderr)."""
    parser = build_parser()
    renamed = _renamed_flag(sys.argv[1:] if argv is None else argv)
    if renamed:
        print(f"rfmitsuba: error: {renamed[0]} is called {renamed[1]} now (see the changelog)", file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from ..core.memory import keep_freed_memory

    keep_freed_memory()
    warnings.formatwarning = _one_line_warning(args.command)
    try:
        if args.variant:
            from ..core import backend

            backend.set_variant(args.variant)
        with sigterm_interrupts():   # kill (SIGTERM) stops a command as Ctrl-C does
            return int(args.func(args) or 0)
    except RfmError as e:
        print(f"rfmitsuba {args.command}: error: {e}", file=sys.stderr)
        return 2
    except BaseException as e:                     # noqa: BLE001 - named below, or raised again
        code, message = _named_fault(e, out=getattr(args, "out", None))
        if code is None:
            raise
        print(f"rfmitsuba {args.command}: {message}", file=sys.stderr)
        return code


def _one_line_warning(command: str):
    """``warnings.formatwarning`` for the CLI: "rfmitsuba COMMAND: warning: MESSAGE", without the
    source file and line a Python user sees."""
    def fmt(message, category, filename, lineno, line=None):
        return f"rfmitsuba {command}: warning: {message}\n"

    return fmt


def _cause_chain(e: BaseException):
    """``e`` and the exceptions it was raised from (``__cause__``, else ``__context__``): Dr.Jit's
    loops re-raise a Ctrl-C or an OSError inside them as a RuntimeError of their own."""
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        yield e
        e = e.__cause__ or e.__context__


def _named_fault(e: BaseException, *, out: str | None = None) -> tuple[int | None, str]:
    """(exit code, one-line message) for a fault a user can cause, or (None, "") for a bug.
    ``out``: the command's output folder (``--out``), named where the error names no path, and
    offered as the way out only where the command has one.

    Ctrl-C: 130, "interrupted; finished work is kept"; SIGTERM: 143, the same; a file-system error (disk full, read-only,
    a file where a folder belongs, permission): 1, naming the path and the cause; out of memory:
    1, with the size asked for."""
    import errno

    chain = list(_cause_chain(e))
    if any(isinstance(x, Terminated) for x in chain):
        return 143, "terminated (SIGTERM); finished work is kept, run the same command to resume"
    if any(isinstance(x, KeyboardInterrupt) for x in chain):
        return 130, "interrupted; finished work is kept, run the same command to resume"
    mem = next((x for x in chain if isinstance(x, MemoryError)), None)
    if mem is not None:
        what = str(mem) or "an allocation failed"
        if "(--" in what:   # the check that raised it names the option (rfmitsuba.core.allocation)
            return 1, f"error: out of memory: {what}"
        return 1, (f"error: out of memory ({what}); ask for fewer positions, states or views per call "
                   "(--positions, --person-positions, --batch)")
    ose = next((x for x in chain if isinstance(x, OSError) and (x.filename or x.errno)), None)
    if ose is not None:
        path = ose.filename if ose.filename is not None else (f"writing under {out}" if out else "(no path)")
        cause = ose.strerror or errno.errorcode.get(ose.errno or 0, str(ose))
        elsewhere = " or write elsewhere (--out)" if out else ""
        hint = {errno.ENOSPC: f"; free space{elsewhere}, finished work is kept",
                errno.EROFS: "; write elsewhere (--out)" if out else "; the folder is read-only: copy it somewhere "
                             "writable and run the command there",
                errno.EACCES: f"; check the permissions{elsewhere}",
                errno.ENOTDIR: "; a file stands where a folder belongs",
                errno.EEXIST: "; a file stands where a folder belongs"}.get(ose.errno, "")
        return 1, f"error: {path}: {cause}{hint}"
    return None, ""


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
