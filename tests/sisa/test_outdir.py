"""Output folders: whole or not at all, never over another folder."""

import re
from pathlib import Path

import pytest

from sisa.core.errors import InputError, RecorderError
from sisa.core.outdir import staged_output_dir


def _make(out: Path, taken_by: str | None = None, fail: bool = False) -> Path:
    """A run writing mine.txt into `out`; meanwhile something else takes the name `out`
    (`taken_by`), or the run fails. Returns the scratch folder it wrote in."""
    with staged_output_dir(out) as scratch:
        (scratch / "mine.txt").write_text("mine")
        if taken_by == "file":
            out.write_text("theirs")
        elif taken_by is not None:
            out.mkdir()
            if taken_by == "folder":
                (out / "theirs.txt").write_text("theirs")
        if fail:
            raise RuntimeError("boom")
    return scratch


def test_a_finished_run_appears_whole(tmp_path):
    out = tmp_path / "run"
    _make(out)
    assert (out / "mine.txt").read_text() == "mine"
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_a_failed_run_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        _make(tmp_path / "run", fail=True)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("taken_by", ["folder", "empty folder", "file"])
def test_a_name_taken_while_running_keeps_both(tmp_path, taken_by):
    """Another run finishing first into the same folder: neither result is lost."""
    out = tmp_path / "run"
    with pytest.raises(InputError, match="appeared while this run was made") as err:
        _make(out, taken_by)
    message = str(err.value)
    assert "\n" not in message
    scratch = Path(message.rsplit("kept in ", 1)[1])
    assert scratch.parent == tmp_path
    assert (scratch / "mine.txt").read_text() == "mine"
    if taken_by == "file":
        assert out.read_text() == "theirs"
    else:
        assert sorted(p.name for p in out.iterdir()) == \
            (["theirs.txt"] if taken_by == "folder" else [])


def test_a_log_that_failed_in_a_run_is_said_gone(tmp_path):
    """A recorder error names its log, inside the scratch folder that goes with the run."""
    out = tmp_path / "run"
    said = ("^" + re.escape(f"cannot write {out / 'flight.mcap'}: No space left on device; "
                            f"nothing was kept ({out} is made whole or not at all)") + "$")
    with pytest.raises(RecorderError, match=said), staged_output_dir(out) as scratch:
        raise RecorderError(f"cannot write {scratch / 'flight.mcap'}: No space left on device")
    assert list(tmp_path.iterdir()) == []


def test_force_replaces_an_output_folder_only_once_the_new_one_is_complete(tmp_path):
    """One policy for every command (issue 33, item 5): an existing output is refused, and
    --force replaces it whole; a run that fails leaves the old one as it was."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with pytest.raises(InputError, match="--force replaces it"), staged_output_dir(out):
        pass
    def fails() -> None:
        with staged_output_dir(out, force=True) as scratch:
            (scratch / "new.txt").write_text("new")
            assert (out / "old.txt").read_text() == "old"  # untouched while it is made
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        fails()
    assert sorted(p.name for p in out.iterdir()) == ["old.txt"]
    with staged_output_dir(out, force=True) as scratch:
        (scratch / "new.txt").write_text("new")
        assert (out / "old.txt").exists()
    assert sorted(p.name for p in out.iterdir()) == ["new.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # nothing left beside


def test_force_never_replaces_a_file_or_a_link_with_a_folder(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "elsewhere")
    for name in ("notes.txt", "link"):
        with pytest.raises(InputError, match="is not a folder: --force replaces only"), \
                staged_output_dir(tmp_path / name, force=True):
            pass
    assert (tmp_path / "notes.txt").read_text() == "mine"
    assert (tmp_path / "link").is_symlink()
