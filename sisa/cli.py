"""The `sisa` command. Each subcommand lives in `sisa.commands.<name>` and registers itself here.

Every error SISA raises on purpose ends as one line on stderr and exit code 2; nothing is left
half-written (commands write into a temporary folder and rename it at the end).
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import math
import signal
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import Final, NoReturn, TextIO

from sisa import __version__
from sisa.commands import say_error, warning_line
from sisa.core.errors import InputError, SisaError
from sisa.core.interrupt import (
    INTERRUPTED_EXIT,
    STOPPED_EXITS,
    TERMINATED_EXIT,
    Terminated,
    exit_code,
    raise_if_stopped,
    stops_noted,
)

Handler = Callable[[argparse.Namespace], int]

# The cyclic collector's thresholds for batch commands (the interpreter's: 700, 10, 10). Starting
# up, a command imports numpy, numba, GDAL and PROJ bindings and scipy and makes numba's typing
# tables: ~300 collections that find almost nothing, 0.2 s of the 1.4 s start-up of `sisa ortho`
# on our VM's slow hour. Collecting every 100 000 new objects instead takes 0.06 s. Real-time
# commands (`real_time_loop` among their defaults) keep the interpreter's short, frequent pauses.
BATCH_GC_THRESHOLDS = (100_000, 20, 10)

EPILOG = """examples:
  sisa scenario show garrotxa        resolved scenario and its derived figures
  sisa truth --preset bench --out runs/bench-truth
                                     trajectory, DEM, scene and ground points of a scenario
  sisa simulate --preset bench --out runs/bench
                                     a whole flight in virtual time: flight.mcap + truth
  sisa emulate --preset bench --out runs/bench-emu
                                     the three devices in real time on virtual ports
  sisa sync runs/bench/flight.mcap --scanner runs/bench/scanner --out runs/bench/sync
                                     every INS record and scan line on GPS time
  sisa georef runs/bench/flight.mcap --scanner runs/bench/scanner \\
       --dem runs/bench/terrain/dem.tif --out runs/bench/georef
                                     every pixel on the DEM: IGM, ortho, mosaic, footprints
  sisa ortho runs/bench/process/segment_000_igm.bil runs/bench/scanner/segment_000.bil \\
       --cell 2 --out seg0_2m.tif    one segment mapped again, here at 2 m cells
  sisa process runs/bench            sync + georeference + report with accuracy vs truth
  sisa campaign process season.toml --out season
                                     every flight of a campaign on Dask: COGs, STAC catalog
  sisa <command> --help              every command shows an example

exit codes: 0 complete; 3 finished, but short of what the inputs promised (the headline
says how much, and a last line on stderr); 2 bad input or usage (one line on stderr);
1 failed; 130 interrupted (Ctrl-C), 143 terminated (SIGTERM).
"""


class Parser(argparse.ArgumentParser):
    """argparse, with a usage error in one line, as every other error (argparse printed its
    whole usage block first); the subcommands' parsers are of this class too."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (`{self.prog} --help` shows the usage)\n")


def build_parser() -> argparse.ArgumentParser:
    from sisa.commands import (
        Formatter,
        SubParsers,
        bench,
        calibrate,
        campaign,
        emulate,
        georef,
        log,
        ortho,
        process,
        record,
        replay,
        scenario,
        simulate,
        sync,
        truth,
    )

    parser = Parser(
        prog="sisa", formatter_class=Formatter, epilog=EPILOG,
        description="SISA: emulate, record, synchronise and georeference an airborne "
                    "pushbroom scanner with its INS and GPS receiver.")
    parser.add_argument("--version", action="version", version=f"sisa {__version__}")
    # subcommands' parsers are Parsers (argparse makes them of the parent's class)
    sub: SubParsers[argparse.ArgumentParser] = parser.add_subparsers(  # type: ignore[assignment]
        dest="command", metavar="COMMAND")
    scenario.register(sub)
    truth.register(sub)
    simulate.register(sub)
    emulate.register(sub)
    record.register(sub)
    replay.register(sub)
    bench.register(sub)
    log.register(sub)
    sync.register(sub)
    georef.register(sub)
    ortho.register(sub)
    calibrate.register(sub)
    process.register(sub)
    campaign.register(sub)
    return parser


def main(argv: Sequence[str] | None = None, *, batch_gc: bool = False) -> int:
    """Run one command; `batch_gc`: a batch command runs with BATCH_GC_THRESHOLDS (the
    console script; not for tests, which call this in their own process)."""
    try:  # the commands' imports: Ctrl-C there is an interruption like any other
        parser = build_parser()
        args = parser.parse_args(argv)
    except KeyboardInterrupt:
        named = next((a for a in (sys.argv[1:] if argv is None else argv)
                      if not a.startswith("-")), None)
        print(f"sisa{'' if named is None else ' ' + named}: interrupted", file=sys.stderr)
        return INTERRUPTED_EXIT
    args.command_line = list(sys.argv[1:] if argv is None else argv)  # as typed, for records
    handler: Handler | None = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return 2
    _command[0] = args.command
    if batch_gc and not getattr(args, "real_time_loop", False):
        gc.set_threshold(*BATCH_GC_THRESHOLDS)
    try:
        with stops_noted():
            _check_finite(args)
            code = handler(args)
            if code not in STOPPED_EXITS:  # a stop the command did not answer: C code lost it
                raise_if_stopped()
            return code
    except Terminated:
        print(f"sisa {args.command}: terminated", file=sys.stderr)
        return TERMINATED_EXIT
    except SisaError as exc:
        say_error(f"sisa {args.command}: error: {_cut(str(exc))}")
        return 2
    except BrokenPipeError:  # `sisa ... | head`: the reader left, that is fine
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print(f"sisa {args.command}: interrupted", file=sys.stderr)
        return INTERRUPTED_EXIT
    finally:
        _command[0] = None


MAX_ERROR_CHARS = 2000  # an error line, whatever a message quotes (its inputs are cut already)


def _cut(text: str) -> str:
    return text if len(text) <= MAX_ERROR_CHARS else text[:MAX_ERROR_CHARS - 1] + "…"


def _check_finite(args: argparse.Namespace) -> None:
    """Every number given on the command line is finite: no option has a use for nan or inf,
    and they slip through range checks (nan <= 0 is False)."""
    for name, value in vars(args).items():
        for v in value if isinstance(value, list) else [value]:
            if isinstance(v, float) and not math.isfinite(v):
                raise InputError(f"--{name.replace('_', '-')} {v}: must be a finite number")


def run() -> None:
    """The console script: `main`, then exit without the interpreter's last collections.

    By the end of a command the process holds a few hundred thousand long-lived objects (numba's
    typing tables, GDAL and PROJ bindings, scipy); at exit the interpreter's cyclic collector
    would walk them all again while it tears the modules down, 0.1-0.5 s of a short command's
    time on our 2-core VM. Everything is written and closed by now, so they are frozen out of
    its reach: they are freed with the process. Not in `main`, which tests call in-process."""
    warnings.showwarning = _one_line_warning
    try:
        code = main(batch_gc=True)
    except KeyboardInterrupt as exc:  # held back by C code past the command's end
        code = exit_code(exc)
    if code in STOPPED_EXITS:
        _forget_handled_interrupt()
    gc.freeze()
    # The command is over. The interpreter gives signals their default action back as it shuts
    # down, so a late Ctrl-C or stop (`sisa bench` asking a child that had the terminal's own
    # already, a second Ctrl-C) would turn this exit into death by signal, the run's status
    # lost: ignored from here.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    sys.exit(code)


def _forget_handled_interrupt() -> None:
    """A Ctrl-C that came while an import ran code through CPython's PyRun_* API (one of the
    libraries a command imports does) is marked unhandled by CPython, though main() handled it:
    `python -m sisa.cli` then said `interrupted` and died of SIGINT at exit (-2), not exit 130
    (1 in 3 Ctrl-Cs in `sisa sync`'s first second). The mark is a CPython internal, cleared
    here; on an interpreter without it, nothing is done."""
    try:
        mark = ctypes.c_int.in_dll(ctypes.pythonapi, "_Py_UnhandledKeyboardInterrupt")
    except (ValueError, AttributeError):
        return
    mark.value = 0


OWN_PACKAGES: Final = frozenset({"sisa", "emulators", "acquisition", "recorder", "postproc"})


_command: list[str | None] = [None]  # names the warnings once main() knows the command


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str,
                      lineno: int, file: TextIO | None = None, line: str | None = None
                      ) -> None:
    """SISA's own warnings (a DEM's undeclared voids, an SBET cut mid-record) are said to
    the user in one line, like its errors and named by the command as they are; others keep
    Python's form, source line included."""
    if category.__module__.split(".")[0] in OWN_PACKAGES:
        text = warning_line(_command[0], message)
    else:
        text = warnings.formatwarning(message, category, filename, lineno, line)
    print(text, end="", file=file or sys.stderr)


if __name__ == "__main__":
    run()
