"""Output folders that appear whole or not at all, and never replace an existing one."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sisa.errors import InputError, RecorderError


@contextmanager
def staged_output_dir(out: Path) -> Iterator[Path]:
    """Yield a scratch folder beside `out`; rename it to `out` only if the block succeeds."""
    out = Path(out)
    if out.exists():
        raise InputError(f"{out} already exists: choose a new output folder (runs are never "
                         "overwritten)")
    parent = out.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create {parent}: {exc.strerror}") from None
    scratch = parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(scratch, ignore_errors=True)
    try:
        scratch.mkdir()
    except OSError as exc:  # a read-only or special folder (/sys, /proc)
        raise InputError(f"cannot write in {parent}: {exc.strerror}") from None
    try:
        yield scratch
    except RecorderError as exc:  # the log it names went with the scratch folder: say so
        shutil.rmtree(scratch, ignore_errors=True)
        said = str(exc).replace(str(scratch), str(out))  # the run as the user named it
        raise RecorderError(f"{said}; nothing was kept ({out} is made whole or not at "
                            "all)") from exc
    except BaseException:
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    # Something may have taken the name while the run was made (another run to the same
    # folder): keep the result where it is rather than lose it or replace the other one.
    kept = f"the result is kept in {scratch}"
    if out.exists() or out.is_symlink():
        raise InputError(f"{out} appeared while this run was made: {kept}")
    try:
        os.replace(scratch, out)
    except OSError as exc:
        raise InputError(f"cannot move the result to {out} ({exc.strerror}): {kept}") from None
