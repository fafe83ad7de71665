"""One module per `sisa` subcommand; each has `register(subparsers)`."""

from __future__ import annotations

import argparse

SubParsers = argparse._SubParsersAction  # the type argparse gives subcommand registries


class Formatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the examples in --help laid out as written."""


def add_command(sub: SubParsers[argparse.ArgumentParser], name: str, help_text: str,
                example: str) -> argparse.ArgumentParser:
    """A subcommand parser whose --help ends with a worked example."""
    return sub.add_parser(name, help=help_text, description=help_text,
                          epilog=f"example:\n  {example}", formatter_class=Formatter)
