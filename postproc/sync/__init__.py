"""Stage 1, time synchronisation: every INS record and every scan line on GPS time, from the
flight log and the scanner's own recording only (docs/sync.md).

Inside, in the order data flows: `flightlog` reads what the sync needs from the log; `pulses`
and `clockmap` put the sync unit's pulses and the host's clock on GPS time; `insclock`,
`coarse`, `pattern`, `insfit`, `insjumps` and `insrecords` find the INS clock's runs (across
its jumps), match its latched pulses to the unit's pulse pattern and fit each run; `lines` and
`linefit` time every scan line by its frame counter; `report` says what was found and how good
it is; `files` reads the scanner folder and writes the results; `pipeline` runs them in order.
Other stages and the commands use only the names below.
"""

from postproc.sync.config import SyncConfig, TimeStatus
from postproc.sync.files import (
    FRAME_COUNTER_MAX,
    SEGMENT_MAX,
    read_scanner_lines,
    unlisted_line_notes,
    write_ins_times,
    write_line_times,
    write_photo_times,
    write_report,
    write_time_tables,
)
from postproc.sync.flightlog import (
    WANTED,
    GpsTimes,
    HeaderColumns,
    InsColumns,
    SisaColumns,
    SyncInput,
    read_sync_input,
    sync_input_from_columns,
)
from postproc.sync.photos import PhotoStatus, PhotoTimes, PhotoTimeSource
from postproc.sync.pipeline import sync_log, synchronise
from postproc.sync.report import (
    AMBIGUOUS_HINT,
    header_order_note,
    host_steps_note,
    no_ins_timed_note,
    untimed_lines_note,
)
from postproc.sync.results import InsSolution, InsTimes, LineTimes, SyncResult

__all__ = [
    "AMBIGUOUS_HINT", "FRAME_COUNTER_MAX", "SEGMENT_MAX", "WANTED", "GpsTimes", "HeaderColumns",
    "InsColumns", "InsSolution", "InsTimes", "LineTimes", "PhotoStatus", "PhotoTimeSource",
    "PhotoTimes", "SisaColumns", "SyncConfig",
    "SyncInput", "SyncResult", "TimeStatus", "header_order_note", "host_steps_note",
    "no_ins_timed_note", "read_scanner_lines",
    "read_sync_input", "sync_input_from_columns", "sync_log", "synchronise",
    "unlisted_line_notes", "untimed_lines_note", "write_ins_times", "write_line_times",
    "write_photo_times", "write_report", "write_time_tables",
]
