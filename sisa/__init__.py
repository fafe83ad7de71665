"""SISA: the shared vocabulary (time scale, errors, frames) and the `sisa` command.

The four subsystems live in their own top-level packages (emulators, acquisition, recorder,
postproc); this package holds only what every one of them speaks, so that postproc can share it
without importing the emulators or the acquisition.
"""

__version__ = "0.1.0"
