"""What the command line's subcommands share: the one-line user error and the parser that raises it."""

from __future__ import annotations

import argparse

__all__ = ["CLIError", "Parser"]


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        # argparse prints a usage block; one line with a pointer to --help reads better
        raise CLIError(f"{message} (see '{self.prog} --help')")
