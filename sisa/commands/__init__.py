"""One module per `sisa` subcommand; each has `register(subparsers)`."""

from __future__ import annotations

import argparse
import os
import sys
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from sisa.core.errors import InputError
from sisa.core.outdir import name_taken

if TYPE_CHECKING:
    from emulators.scenario import Scenario

SubParsers = argparse._SubParsersAction  # the type argparse gives subcommand registries


class Formatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the examples in --help laid out as written."""


FLIGHT_HELP = ("the flight log (MCAP; the numbered parts of a split recording are found beside "
               "it), or every part (read in part order, whatever the order given)")


def warning_line(command: str | None, text: object) -> str:
    """A warning as the user reads it: one line, named by the command (if known) as its errors
    are."""
    return f"sisa{'' if command is None else ' ' + command}: warning: {text}\n"


def say_warning(command: str, text: str) -> None:
    """A warning to the user: one line on stderr, named by the command, like its errors."""
    print(warning_line(command, text), end="", file=sys.stderr, flush=True)


# A command run by another (`sisa bench`'s emulator and recorder) gives its one error line to
# the descriptor this names, when set, instead of stderr: the parent says one line for the run.
ERROR_FD_ENV = "SISA_ERROR_FD"


def say_error(line: str) -> None:
    """A command's error line (sisa.cli): to the descriptor in SISA_ERROR_FD if it takes it,
    else to stderr."""
    fd = os.environ.get(ERROR_FD_ENV, "")
    if fd.isdigit():
        try:
            os.write(int(fd), f"{line}\n".encode("utf-8", "replace"))
            return
        except OSError:  # not open (a stale setting): stderr, as always
            pass
    print(line, file=sys.stderr)


def flight_parts(files: Sequence[Path]) -> list[Path]:
    """`recorder.parts.flight_parts`, imported when a command uses it: building the parser
    (every command's first step, and all an argument error needs) imports no numpy."""
    from recorder.parts import flight_parts as parts

    return parts(files)


def check_inputs(*given: tuple[str, Path | Sequence[Path] | None, str]) -> None:
    """Every input named on the command line exists, as the kind of thing it must be, before
    a command imports its heavy machinery: `sisa process /nonexistent` spent ~1.5 s of CPU
    importing the georeferencing before it said so. Each is (option or '' for a positional,
    the path(s) or None, "file" | "folder" | "any")."""
    for option, paths, kind in given:
        if paths is None:
            continue
        for path in [paths] if isinstance(paths, Path) else paths:
            name = f"{option} {path}" if option else str(path)
            if not name_taken(path, option) or not path.exists():
                what = {"file": "file", "folder": "folder"}.get(kind, "file or folder")
                raise InputError(f"{name}: no such {what}")
            if kind == "file" and path.is_dir():
                raise InputError(f"{name}: is a folder, not a file")
            if kind == "folder" and not path.is_dir():
                raise InputError(f"{name}: is a file, not a folder")


# Exit codes (README, "How every command behaves"): 0 complete; 3 finished, but short of what
# its inputs promised (the headline says how much); 2 bad input or usage (sisa.cli); 1 failed
# (an unexpected error); 130 interrupted, 143 terminated.
EXIT_INCOMPLETE = 3


def finished_with_losses(command: str, what: str) -> int:
    """Say on stderr that the command finished short of what its inputs promised, and return
    the exit code that tells a script so."""
    print(f"sisa {command}: finished with losses: {what} (exit code {EXIT_INCOMPLETE})",
          file=sys.stderr, flush=True)
    return EXIT_INCOMPLETE


MAX_SEED = 2**32 - 1  # numpy's seeds, and the scenario's


def check_seed(seed: int | None, option: str = "--seed") -> None:
    if seed is not None and not 0 <= seed <= MAX_SEED:
        raise InputError(f"{option} {seed}: use a whole number from 0 to {MAX_SEED}")


def check_port(port: int, option: str = "--pulses-port") -> None:
    if not 0 <= port <= 65535:
        raise InputError(f"{option} {port}: a TCP port is 0 to 65535 (0: any free port)")


def new_file_arg(text: str) -> Path:
    """argparse type of an argument naming a new file: a name ending in '/' names a folder, and
    Path would drop the slash and make a file of that name."""
    if text.endswith(("/", os.sep)):
        raise argparse.ArgumentTypeError(f"{text}: ends in '/': name a new file, not a folder")
    return Path(text)


ENDPOINTS_MAX_BYTES = 65536  # an endpoints file is a few lines of JSON


def check_endpoints_path(path: Path | None) -> None:
    """--endpoints names a file in an existing folder: checked before any port opens, so a
    wrong path costs nothing (no ports, no run folder). An existing file is replaced only if
    it is an endpoints file (a script reusing its path); anything else there (a flight log
    named by a typo) is refused, not overwritten."""
    if path is None:
        return
    taken = name_taken(path, "--endpoints")
    if path.is_dir():
        raise InputError(f"--endpoints {path}: is a folder, not a file")
    if not path.parent.is_dir():
        raise InputError(f"--endpoints {path}: {path.parent} is not a folder")
    if taken and not _is_endpoints_file(path):
        raise InputError(f"--endpoints {path}: exists and is not an endpoints file (JSON of "
                         "device names and ports): it would be replaced; name a new file")


def _is_endpoints_file(path: Path) -> bool:
    from sisa.core.bounded import json_loads

    try:
        if not path.is_file() or path.stat().st_size > ENDPOINTS_MAX_BYTES:
            return False
        found = json_loads(path.read_bytes())  # nesting bounded
    except (OSError, ValueError):  # (UnicodeDecodeError is a ValueError)
        return False
    return isinstance(found, dict) and all(isinstance(v, str) for v in found.values())


def write_endpoints(path: Path, endpoints: dict[str, str]) -> None:
    """Written whole (a temporary file renamed), so a script polling for it never reads half."""
    import json

    from sisa.core.outdir import write_whole

    try:
        write_whole(path, json.dumps(endpoints, indent=2) + "\n")
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror or exc}") from None


# The one rule for Ctrl-C (and SIGTERM), in every command's --help and the README: a command
# stops at once and never leaves anything half-written. What it computes is removed (outputs
# appear whole or not at all), exit 130 (143 for SIGTERM); what it records is kept, a shorter
# but complete recording. `record`, `emulate` and `replay` run until stopped: Ctrl-C is how they
# end (exit 0).
STOP_RULE = ("Ctrl-C (or SIGTERM) stops it at once; nothing of its output is left behind (an "
             "output appears whole or not at all); exit 130 (143 for SIGTERM).")
STOP_RULES = {
    "bench": "Ctrl-C (or SIGTERM) stops the recorder, then the emulator, at any moment: the run "
             "recorded so far is kept, whole and readable, once the recorder has begun its "
             "flight log (before that, nothing is left); exit 130 (143 for SIGTERM).",
    "record": "Ctrl-C (or SIGTERM) is how a recording ends: the file is closed, whole and "
              "readable; exit 0.",
    "emulate": "Ctrl-C (or SIGTERM) is how an emulation ends: the devices stop, the scanner's "
               "recording and the truth so far are kept; exit 0.",
    "replay": "Ctrl-C (or SIGTERM), or q, is how a replay ends: the ports close; exit 0.",
}


def add_command(sub: SubParsers[argparse.ArgumentParser], name: str, help_text: str,
                example: str) -> argparse.ArgumentParser:
    """A subcommand parser whose --help ends with a worked example and what Ctrl-C does."""
    return sub.add_parser(name, help=help_text, description=help_text,
                          epilog=f"example:\n  {example}\n\n"
                                 + textwrap.fill(STOP_RULES.get(name, STOP_RULE), 79),
                          formatter_class=Formatter)


def add_force_arg(parser: argparse.ArgumentParser, what: str = "output folder") -> None:
    """--force, the one way any command replaces an existing output."""
    parser.add_argument("--force", action="store_true",
                        help=f"replace an existing {what} (without it, an existing one is "
                             "refused); the new one is made beside it and takes its place "
                             "only once complete")


def add_scenario_args(parser: argparse.ArgumentParser, what: str = "scenario") -> None:
    """--preset NAME | --scenario FILE, the way every command names its scenario."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--preset", default="bench", help=f"{what} preset (default: bench)")
    group.add_argument("--scenario", type=Path, help=f"{what} TOML file")


def scenario_from_args(args: argparse.Namespace) -> Scenario:
    return load_scenario_arg(args.scenario if args.scenario is not None else args.preset)


def load_scenario_arg(name_or_path: str | Path) -> Scenario:
    """`emulators.scenario.load_scenario`, with a name no file can have (too long) an
    InputError."""
    from emulators.scenario import load_scenario

    name_taken(Path(name_or_path))
    return load_scenario(name_or_path)
