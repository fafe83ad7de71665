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
