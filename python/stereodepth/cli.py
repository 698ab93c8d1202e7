"""The ``stereodepth`` command: ``calc`` here; other subcommands register from their modules.

Bad input prints one line, ``stereodepth <command>: error: ...``, and exits with status 2:
the message names the option as the user typed it (``--subpixel-px``, not the library's
``disparity_step_px``), and usage mistakes that argparse finds end with a pointer to
``--help`` instead of the whole usage text. A missing optional extra (matplotlib for
``--plot``, say) or a file that fails as it is written prints one line and exits with 1. Ctrl-C
prints "interrupted" and exits with 130; SIGTERM (``timeout``, ``kill``) is handled as
Ctrl-C for the command's duration, through the same clean-up, then prints "terminated" and
exits with 143; except ``serve``, for which either signal is its normal end ("stopped", 0),
and a command whose outputs are already in place (:func:`outputs_committed`), which ends as
done.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import math
import os
import re
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from typing import Any, NoReturn

from .rig import StereoRig

# Modules that add a subcommand: each has register(subparsers) that adds its parser with
# set_defaults(func=run), where run(args) -> int. They import heavy dependencies inside run.
_SUBCOMMAND_MODULES: tuple[str, ...] = (
    "stereodepth.evaluation",
    "stereodepth.web.serve",
    "stereodepth.batch",
    "stereodepth.match_command",
)


class UsageError(Exception):
    """Bad input on the command line: reported in one line, exit status 2."""


class Terminated(KeyboardInterrupt):
    """SIGTERM during a command (``timeout``, ``kill``, a process manager): raised where
    Ctrl-C's KeyboardInterrupt would be, so that the same clean-up runs; the command then
    says "terminated" and exits with 143 (128 + 15) instead of 130."""


#: Whether SIGTERM arrived during the command that :func:`main` runs.
_terminated = False


def terminated() -> bool:
    """Whether the running command got SIGTERM (its exit status is then 143)."""
    return _terminated


#: Whether the running command has put its outputs in place (:func:`outputs_committed`).
_committed = False


def outputs_committed() -> None:
    """Said by a command once its outputs are in place (``match``'s set renamed over the
    earlier one): a Ctrl-C or SIGTERM that comes while it ends no longer makes its exit
    status 130 or 143, which say that the run stopped and left the earlier outputs as they
    were. It ends with the status it had (0)."""
    global _committed
    _committed = True


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """For the block's duration SIGTERM is handled as Ctrl-C is at that moment: by the
    SIGINT handler in place when it is one of ours (batch's stop flag on Dask), else by
    raising :class:`Terminated` (a KeyboardInterrupt). Python's default for SIGTERM was to
    die at once: a half-written set of outputs, batch's lock file left, no report. A no-op
    outside the main thread, where handlers cannot be set."""
    global _terminated
    _terminated = False
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        global _terminated
        _terminated = True
        current = signal.getsignal(signal.SIGINT)
        if callable(current) and current is not signal.default_int_handler:
            current(signal.SIGINT, frame)
            return
        raise Terminated

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def signals_held(
    signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM),
) -> Iterator[list[int]]:
    """For the block's duration ``signals`` (SIGINT and SIGTERM) are only recorded in the
    yielded list, not acted on: for a step that must not stop halfway (renaming a finished
    set of outputs into place, submitting batch's pairs, starting a Dask cluster). The caller
    decides what a recorded signal means afterwards. A no-op outside the main thread."""
    caught: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield caught
        return

    def record(signum: int, frame: Any) -> None:
        caught.append(signum)

    previous = {sig: signal.signal(sig, record) for sig in signals}
    try:
        yield caught
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def import_uninterrupted(*modules: str) -> None:
    """Imports ``modules`` with Ctrl-C and SIGTERM held until the imports end, then acted on.

    matplotlib's compiled modules are pybind11's, whose module set-up turns any exception
    into ImportError: a Ctrl-C during ``import matplotlib`` read as "colour maps need
    matplotlib" (exit 1, the extra installed), and could leave the interpreter to abort at
    exit. Raises the modules' ImportError; a signal that came meanwhile is raised after it."""
    import importlib

    with signals_held() as caught:
        try:
            for name in modules:
                importlib.import_module(name)
        finally:
            pending = list(caught)
    if pending:
        signal.raise_signal(pending[0])


def one_line(text: object) -> str:
    """A message on one line: its lines joined with "; "."""
    return "; ".join(line.strip() for line in str(text).strip().splitlines() if line.strip())


# Every character str.splitlines breaks at, as Python writes it in a string literal.
_LINE_BREAKS = {ord(c): repr(c)[1:-1] for c in "\n\r\v\f\x1c\x1d\x1e\x85\u2028\u2029"}


def escape_line_breaks(text: object) -> str:
    """``text`` on one line, its line breaks written as escapes (``\\n``, ``\\u2028``), so
    that a name holding one (a file or folder name may) is shown as it is, unlike
    :func:`one_line`, which would make it a different name."""
    return str(text).translate(_LINE_BREAKS)


def path_arg(value: str) -> str:
    """An argparse ``type`` for a file or folder argument: an empty one (``-o "$OUT"`` with
    OUT unset) is a usage error naming the argument, not the current folder, which pathlib
    makes of "", and so is one with a name longer than a file name may be (it was
    "[Errno 36] File name too long" with exit status 1 and no argument named; batch's OUTDIR
    and --report only once they were written)."""
    from pathlib import Path

    if not value:
        raise argparse.ArgumentTypeError("expected a path, got ''")
    for part in Path(value).parts:
        problem = name_too_long(part)
        if problem is not None:
            raise argparse.ArgumentTypeError(problem)
    return value


def threads_out_of_range(threads: int | None) -> str | None:
    """The message for a ``--threads`` the matchers cannot take, or None: the same words in
    ``match``, ``batch`` and ``eval``, checked before any work (beyond a C int the matcher's
    own message named ``threads``, after the images had been read)."""
    from . import _validate as check

    if threads is None or 0 <= threads <= check.MAX_NATIVE_INT:
        return None
    return (
        f"--threads must be an integer >= 0 and <= {check.MAX_NATIVE_INT} (0: every core), "
        f"got {threads}"
    )


def name_too_long(name: str) -> str | None:
    """Why ``name`` (one file or folder name, no separators) cannot be a file name, or None:
    more bytes than NAME_MAX (:data:`stereodepth.io.NAME_MAX_BYTES`)."""
    from .io import NAME_MAX_BYTES

    size = len(os.fsencode(name))
    if size <= NAME_MAX_BYTES:
        return None
    shown = name if len(name) <= 60 else name[:57] + "..."
    return (
        f"the name {shown!r} is {size} bytes long, more than a file name may be "
        f"({NAME_MAX_BYTES} bytes)"
    )


class ArgumentParser(argparse.ArgumentParser):
    """argparse, with usage errors in one line: ``PROG: error: MESSAGE (see PROG --help)``,
    exit status 2. Subcommand parsers inherit the class (add_subparsers uses the parent's)."""

    #: What argparse takes for a negative number rather than an option: its own rule (-3, -.5,
    #: -2.5) misses exponents and inf, so ``--doffs-px -1e9`` was "expected one argument".
    #: (Python 3.13's argparse accepts these already; none of our options looks like one.)
    _NEGATIVE_NUMBER = re.compile(
        r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.I
    )

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = self._NEGATIVE_NUMBER

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


#: calc's options by the names the library gives them in its messages.
_CALC_FLAGS: dict[str, str] = {
    "baseline_mm": "--baseline-mm",
    "focal_mm": "--focal-mm",
    "pixel_um": "--pixel-um",
    "focal_px": "--focal-px",
    "doffs_px": "--doffs-px",
    "width_px": "--width-px",
    "height_px": "--height-px",
    "disparity_px": "--disparity-px",
    "disparity_step_px": "--subpixel-px",
    "max_disparity_px": "--max-disparity-px",
    "disparities_px": "--table-disparities-px",
}
_CALC_NAMES = re.compile(r"\b(" + "|".join(sorted(_CALC_FLAGS, key=len, reverse=True)) + r")\b")


def _as_flags(message: str) -> str:
    """A library message with calc's parameter names replaced by its options."""
    return _CALC_NAMES.sub(lambda m: _CALC_FLAGS[m[1]], message)


def key_value_option(text: str) -> tuple[str, Any]:
    """argparse type of ``--option KEY=VALUE``: the value as bool, None, int, float or str,
    or a tuple of those for comma-separated values (``intensity_range=0,4095``)."""
    key, sep, raw = text.partition("=")
    if not sep or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", key):
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE with KEY a name, got {text!r}")
    if "," in raw:
        return key, tuple(_scalar(part.strip()) for part in raw.split(","))
    return key, _scalar(raw)


class KeyValueOnce(argparse.Action):
    """argparse action of a repeatable ``--option KEY=VALUE`` (``type=key_value_option``):
    appends the (key, value) pairs, and a KEY given twice is a usage error naming both values
    (with ``action="append"`` the last one was used without a word)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        pairs = list(getattr(namespace, self.dest) or [])
        key, value = values
        for given, old in pairs:
            if given == key:
                parser.error(
                    f"{option_string} {key} is given twice ({old!r} and {value!r}): give it once"
                )
        setattr(namespace, self.dest, [*pairs, (key, value)])


def _scalar(raw: str) -> Any:
    """One value of ``--option``: bool, None, int, float or str."""
    low = raw.lower()
    value: Any
    if low in ("true", "false"):
        value = low == "true"
    elif low == "none":
        value = None
    else:
        try:
            value = int(raw)
        except ValueError:
            try:
                value = float(raw)
            except ValueError:
                value = raw
    return value


def _rig_from_args(args: argparse.Namespace) -> StereoRig:
    if args.focal_px is not None:
        if args.focal_mm is not None or args.pixel_um is not None:
            raise UsageError("give either --focal-px, or --focal-mm and --pixel-um, not both")
        return StereoRig.from_pixels(
            args.baseline_mm,
            args.focal_px,
            width_px=args.width_px,
            doffs_px=args.doffs_px,
            height_px=args.height_px,
        )
    if args.focal_mm is None or args.pixel_um is None:
        raise UsageError("give --focal-mm and --pixel-um (or --focal-px)")
    if args.doffs_px:
        raise UsageError("--doffs-px goes with --focal-px (a calibration in pixels)")
    return StereoRig(
        args.baseline_mm,
        args.focal_mm,
        args.pixel_um,
        width_px=args.width_px,
        height_px=args.height_px,
    )


def _fmt(value: Any, unit: str = "", digits: int = 6) -> str:
    if value is None:  # not applicable: the rig lacks what it needs (pixel size, width)
        return "-"
    if isinstance(value, float):
        if math.isinf(value):
            return "inf"
        text = f"{value:.{digits}g}"
    else:
        text = str(value)
    return f"{text} {unit}".rstrip()


def _print_summary(rig: StereoRig, s: dict[str, Any]) -> None:
    lines = [("rig", repr(rig)), ("focal length", _fmt(s["focal_px"], "px"))]
    if s["hfov_deg"] is not None:
        lines.append(("horizontal field of view", _fmt(s["hfov_deg"], "deg", 4)))
    if s["vfov_deg"] is not None:
        lines.append(("vertical field of view", _fmt(s["vfov_deg"], "deg", 4)))
    lines.append(("max depth (1 px disparity)", _fmt(s["max_depth_m"], "m")))
    if s["disparity_px"] is not None:
        lines.append(("disparity", _fmt(s["disparity_px"], "px")))
        lines.append(("disparity on the sensor", _fmt(s["disparity_mm"], "mm")))
        lines.append(("depth", _fmt(s["depth_m"], "m")))
        lines.append(("depth resolution (1 px)", _fmt(s["depth_resolution_m"], "m")))
        lines.append(("  exact, Z(d) - Z(d+1)", _fmt(s["depth_resolution_exact_m"], "m")))
        if s["disparity_step_px"] != 1.0:
            lines.append(
                (
                    f"depth resolution ({_fmt(s['disparity_step_px'])} px)",
                    _fmt(s["depth_resolution_subpx_m"], "m"),
                )
            )
    if s["min_depth_m"] is not None:
        lines.append(
            (f"min depth (search to {_fmt(s['max_disparity_px'])} px)", _fmt(s["min_depth_m"], "m"))
        )
    width = max(len(k) for k, _ in lines)
    for key, value in lines:
        print(f"{key.ljust(width)}  {value}")


def _add_calc(sub: Any) -> None:
    p = sub.add_parser(
        "calc",
        help="depth, depth resolution and field of view of a stereo rig",
        description="The stereo depth calculator: Z = B*f / (d*p).",
    )
    g = p.add_argument_group("the rig")
    g.add_argument("--baseline-mm", type=float, required=True, help="baseline B in mm")
    g.add_argument("--focal-mm", type=float, help="focal length f in mm")
    g.add_argument("--pixel-um", type=float, help="pixel size p in micrometres")
    g.add_argument("--focal-px", type=float, help="focal length in pixels (replaces the two above)")
    g.add_argument(
        "--doffs-px",
        type=float,
        default=0.0,
        help="principal point offset in px, with --focal-px (Middlebury doffs)",
    )
    g.add_argument("--width-px", type=int, help="image width in px (for the field of view)")
    g.add_argument("--height-px", type=int, help="image height in px")
    q = p.add_argument_group("the question")
    q.add_argument("--disparity-px", type=float, help="disparity d of the target in px")
    q.add_argument(
        "--subpixel-px",
        type=float,
        default=1.0,
        help="the matcher's disparity step in px (default 1)",
    )
    q.add_argument(
        "--max-disparity-px",
        type=float,
        help="top of the disparity search range, for the min depth",
    )
    q.add_argument(
        "--table-disparities-px",
        type=float,
        nargs="+",
        metavar="D",
        help="disparities for the table (default: 1 to 256 px)",
    )
    o = p.add_argument_group("output")
    fmt = o.add_mutually_exclusive_group()
    fmt.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object; JSON has no infinity, so an infinite value (the depth "
        "at disparity 0) is null there, as is a value the rig cannot give (disparity_mm "
        "without --pixel-um, the field of view without --width-px)",
    )
    fmt.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    o.add_argument(
        "--plot",
        type=path_arg,
        metavar="FILE",
        help="write the two charts to this file: PNG, SVG or PDF by its suffix (.png, .svg, "
        ".pdf; needs the 'plot' extra)",
    )
    p.set_defaults(func=_run_calc)
    p.epilog = (
        "In the text output and the table an infinite value (the depth at disparity 0) is "
        "inf and a value the rig cannot give is -; --json writes both as null."
    )


def _run_calc(args: argparse.Namespace) -> int:
    try:
        return _calc(args)
    except (ValueError, TypeError) as exc:
        raise UsageError(_as_flags(one_line(exc))) from exc


def _calc(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.subpixel_px) and args.subpixel_px > 0):
        raise UsageError(
            "--subpixel-px must be the matcher's disparity step, a number > 0 (1 for a "
            f"whole-pixel matcher, 0.25 for a quarter pixel), got {args.subpixel_px:g}"
        )
    if args.plot:
        from pathlib import Path

        from .plotting import FORMATS

        out = Path(args.plot)
        if out.suffix.lower() not in FORMATS:
            raise UsageError(f"--plot must name a .png, .svg or .pdf file, got {args.plot!r}")
        if not out.parent.is_dir():
            from .io import no_folder_reason

            why = no_folder_reason(out)
            raise UsageError(f"--plot: {why}, got {args.plot!r}")
        if out.is_dir():
            raise UsageError(f"--plot must name a file, got the folder {args.plot!r}")
        # Before any work, as match's --out and batch's --report: a file or folder that
        # cannot be written is a usage error (it failed in save_charts, exit 1).
        if not os.access(out.parent, os.W_OK | os.X_OK):
            raise UsageError(
                f"--plot: cannot write in {out.parent} (no write permission), got {args.plot!r}"
            )
        from .io import _refuse_read_only

        try:  # (a link is written through: its target)
            _refuse_read_only(Path(os.path.realpath(out)), out)
        except PermissionError as exc:
            raise UsageError(f"--plot: {exc.strerror}, got {args.plot!r}") from None
    rig = _rig_from_args(args)
    summary = rig.summary(
        args.disparity_px,
        disparity_step_px=args.subpixel_px,
        max_disparity_px=args.max_disparity_px,
        table_disparities_px=args.table_disparities_px,
    )
    if args.plot:
        from .plotting import save_charts

        save_charts(
            rig,
            args.plot,
            disparity_px=args.disparity_px,
            disparity_step_px=args.subpixel_px,
            max_disparity_px=args.max_disparity_px,
        )
    if args.json:
        print(json.dumps(summary, indent=2, allow_nan=False))
        return 0
    _print_summary(
        rig,
        rig.summary(
            args.disparity_px,
            disparity_step_px=args.subpixel_px,
            max_disparity_px=args.max_disparity_px,
            table_disparities_px=args.table_disparities_px,
            finite_only=False,
        ),
    )
    table = rig.table(args.table_disparities_px, disparity_step_px=args.subpixel_px)
    print()
    print(table.to_markdown() if args.markdown else table.to_text())
    if args.plot:
        print(f"\ncharts written to {args.plot}")
    return 0


#: The subcommands whose product is what they print on stdout, and what that is: they refuse
#: to run with stdout closed (match's summary is part of its run: a run that cannot print it
#: fails, and leaves no outputs).
_STDOUT_PRODUCTS: dict[str, str] = {
    "calc": "its results",
    "eval": "its results",
    "match": "its summary",
}


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = ArgumentParser(
        prog="stereodepth", description="Stereo depth, fast: calculator and tools."
    )
    parser.add_argument("--version", action="version", version=f"stereodepth {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_calc(sub)
    for name in _SUBCOMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def _subparser(parser: argparse.ArgumentParser, command: str) -> argparse.ArgumentParser:
    for action in parser._actions:  # argparse keeps its subcommands here
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            found: argparse.ArgumentParser = action.choices[command]
            return found
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        parser = build_parser()
        args, extras = parser.parse_known_args(argv)
    except ValueError as exc:
        # The option help asks the core for the cores this process may use, and the core
        # refuses a mistyped STEREODEPTH_ISA (avx3): one line, before any command runs.
        print(f"stereodepth: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C while the subcommands' modules load: no traceback
        print("stereodepth: interrupted", file=sys.stderr)
        return 130
    if extras:  # name the subcommand whose options these are not
        _subparser(parser, args.command).error(f"unrecognized arguments: {' '.join(extras)}")
    lost = _STDOUT_PRODUCTS.get(args.command)
    if lost is not None and sys.stdout is None:
        # Started with stdout closed (>&-): Python then has no sys.stdout, and print() writes
        # nothing without a word (calc exited 0 having shown nothing).
        print(
            f"stereodepth {args.command}: error: stdout is closed, so {lost} would be lost: "
            "redirect it to a file or to /dev/null",
            file=sys.stderr,
        )
        return 1
    global _committed
    _committed = False
    try:
        with _sigterm_as_interrupt():
            code = int(args.func(args))
        if _terminated and not _committed:  # stopped on SIGTERM as on Ctrl-C, and returned
            print(f"stereodepth {args.command}: terminated", file=sys.stderr)
            return 143
        return code
    except (UsageError, ValueError, TypeError) as exc:
        print(f"stereodepth {args.command}: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except ImportError as exc:  # an optional extra that is not installed
        print(f"stereodepth {args.command}: error: {one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM (Terminated, or one that came after Ctrl-C)
        if _committed:  # it came after the outputs were in place: the run is done
            return 0
        if _terminated:
            print(f"stereodepth {args.command}: terminated", file=sys.stderr)
            return 143
        print(f"stereodepth {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (``stereodepth calc ... | head``): stop quietly, and keep
        # Python from failing again when it flushes stdout at exit.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except OSError as exc:  # a file that cannot be read or written
        print(f"stereodepth {args.command}: error: {one_line(exc)}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    # `python -m stereodepth.cli`: this file then runs as __main__, a second copy of the
    # module, whose UsageError is not the one the subcommands' modules raise (theirs went
    # uncaught, a traceback): run the package's own module, as `python -m stereodepth` does.
    from stereodepth.cli import main as package_main

    sys.exit(package_main())
