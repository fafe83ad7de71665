"""The exit code of a command that finished short of what its inputs promised (3), and the
line it says it in (issue 33, item 6)."""

from __future__ import annotations

import re

INCOMPLETE = 3
LOSSES = re.compile(r"sisa (?P<command>[\w ]+): finished with losses: (?P<what>.+) "
                    r"\(exit code 3\)\n\Z")


def without_losses_line(err: str, command: str = "georef") -> str:
    """stderr without its last line, which must be the command's `finished with losses`."""
    said = LOSSES.search(err)
    assert said is not None, f"no losses line at the end of: {err!r}"
    assert said["command"] == command, err
    return err[:said.start()]
