"""Output folders and files that appear whole or not at all, and never replace an existing
one; the hidden names they are made under are created exclusively and never through a link."""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar, overload

from sisa.core.errors import InputError, RecorderError
from sisa.core.interrupt import raise_if_stopped

T = TypeVar("T")
SCRATCH_NAME_CHARS = 200  # of the output's name in its scratch name (names: 255 bytes)
# a new file, created: it must not exist (no file, no symlink: a link planted under the name
# makes the open fail instead of writing where it points), and a link is never followed
_NEW_FILE_FLAGS = os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
_NEW_FILE_TRIES = 8


def partial_path(final: Path, tag: str = "") -> Path:
    """The hidden name a file or folder is made under beside `final` (same file system: the
    last rename is atomic), this process's (`tag` to tell several apart), and short enough
    for any name the file system takes for `final`."""
    return final.with_name(f".{final.name[:SCRATCH_NAME_CHARS]}.partial-{os.getpid()}{tag}")


def open_new_file(path: Path) -> int:
    """Create `path`, which must not exist (nor be a link, dangling or not): a descriptor open
    for reading and writing. FileExistsError if the name is taken."""
    return os.open(path, _NEW_FILE_FLAGS, 0o644)


def new_private_dir(path: Path) -> None:
    """Create the folder `path`, which must not exist, open to this user alone (an opener for
    `create_partial`): nobody else can plant a link in it under the name a file is then made
    by. For files another library creates by their path: created new in it, not opened over a
    placeholder, which truncating (even empty) has ext4 write the whole file out to disk when
    it is closed (auto_da_alloc), on the writer's time."""
    os.mkdir(path, 0o700)


@overload
def create_partial(final: Path) -> tuple[Path, int]: ...


@overload
def create_partial(final: Path, opener: Callable[[Path], T]) -> tuple[Path, T]: ...


def create_partial(final: Path, opener: Callable[[Path], Any] = open_new_file
                   ) -> tuple[Path, Any]:
    """A new, empty hidden file beside `final` to write it under: (its path, what `opener`
    gave for it: by default a descriptor open for reading and writing). Its name
    (`partial_path`'s, with a random part) cannot be guessed beforehand, and it is created
    exclusively without following a link (`open_new_file`), so nobody sharing the folder can
    aim a symlink planted under it at another file. OSError if it cannot be made."""
    for _ in range(_NEW_FILE_TRIES):
        path = partial_path(final, f"-{secrets.token_hex(4)}")
        try:
            return path, opener(path)
        except FileExistsError:  # (a name already taken, by chance or not: another one)
            continue
    raise FileExistsError(errno.EEXIST, "no free name for a partial file", str(final))


def private_partial(final: Path) -> tuple[Path, Path]:
    """(a new hidden folder beside `final`, open to this user alone, the path in it to make
    `final` by): for a file another library creates by its path (GDAL, rio-cogeo), made new
    rather than over a placeholder (`new_private_dir`). The caller renames the file into place
    and removes the folder, whatever happens."""
    folder, _ = create_partial(final, new_private_dir)
    return folder, folder / final.name


def write_whole(final: Path, data: bytes | str, encoding: str = "utf-8") -> None:
    """Write `final` whole: into a new partial file (`create_partial`), renamed into place
    once written; on failure nothing is left. OSError as the write or the rename gives it."""
    tmp, fd = create_partial(final)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode(encoding) if isinstance(data, str) else data)
        raise_if_stopped()
        os.replace(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def name_taken(path: Path, what: str = "") -> bool:
    """Whether `path` is taken (a dangling symlink too); a name the file system cannot hold
    (longer than its limit) is an InputError rather than a traceback. `what`: the option
    that named it, for the message."""
    try:
        return os.path.lexists(path) or path.exists()
    except OSError as exc:
        if exc.errno != errno.ENAMETOOLONG:
            raise
        raise InputError(f"{what + ' ' if what else ''}{path}: cannot be used as a name: "
                         f"{exc.strerror}") from None


REFUSED = "outputs are never overwritten; --force replaces it"


def refuse_existing(path: Path, what: str = "", *, force: bool = False) -> None:
    """The policy of every command: an existing output is refused, unless --force (then it is
    replaced whole, once the new one is complete). `what`: the option that named it."""
    if name_taken(path, what) and not force:
        named = f"{what} {path}" if what else str(path)
        raise InputError(f"{named} already exists: choose a new name ({REFUSED})")


@contextmanager
def staged_output_dir(out: Path, *, force: bool = False) -> Iterator[Path]:
    """Yield a scratch folder beside `out`; rename it to `out` only if the block succeeds.
    An existing `out` is refused, or with `force` (a folder only) replaced by the new one
    once it is complete: until then the old one is untouched."""
    out = Path(out)
    if name_taken(out):
        if not force:
            raise InputError(f"{out} already exists: choose a new output folder (runs are "
                             f"never overwritten; --force replaces it)")
        if out.is_symlink() or not out.is_dir():
            raise InputError(f"{out} exists and is not a folder: --force replaces only an "
                             "output folder")
    parent = out.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create {parent}: {exc.strerror}") from None
    scratch = partial_path(out)
    shutil.rmtree(scratch, ignore_errors=True)
    try:
        scratch.mkdir()
    except OSError as exc:  # a read-only or special folder (/sys, /proc)
        raise InputError(f"cannot write in {parent}: {exc.strerror}") from None
    try:
        yield scratch
        raise_if_stopped()  # never put in place after a stop, even one C code lost
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
    if (out.exists() or out.is_symlink()) and not force:
        raise InputError(f"{out} appeared while this run was made: {kept}")
    try:
        if force and out.is_dir() and not out.is_symlink():
            replace_dir(scratch, out)
        else:
            os.replace(scratch, out)
    except OSError as exc:
        raise InputError(f"cannot move the result to {out} ({exc.strerror}): {kept}") from None


def replace_dir(new: Path, old: Path) -> None:
    """Put the finished folder `new` in the place of the folder `old`: `old` is renamed aside,
    `new` renamed into place (put back if that fails), then `old` removed. At every moment the
    name holds a complete folder, but for the instant between the two renames."""
    aside = partial_path(old, ".old")
    shutil.rmtree(aside, ignore_errors=True)
    os.rename(old, aside)
    try:
        os.rename(new, old)
    except BaseException:
        os.rename(aside, old)
        raise
    shutil.rmtree(aside, ignore_errors=True)

