"""One calibration from its inputs to its result: build the adjustment, solve it with blunder
rejection, and assemble what it found. Apart from `adjust` so that the report, which reads the
adjustment's types, is imported by neither side of it."""

from __future__ import annotations

from postproc.calibration.adjust import (
    CalibrationInput,
    CalibrationOptions,
    CalibrationResult,
    adjust,
    build,
)
from postproc.calibration.report import assemble


def calibrate(inp: CalibrationInput, opt: CalibrationOptions | None = None
              ) -> CalibrationResult:
    opt = opt or CalibrationOptions()
    adj = build(inp, opt)
    sol, blunders = adjust(adj, opt)
    return assemble(inp, opt, adj, sol, blunders)
