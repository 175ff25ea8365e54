"""What the command line's subcommands share: the one-line user error, the parser that raises it, the compile cache."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

__all__ = ["CLIError", "Parser", "compile_cache_dir", "use_compile_cache"]


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        # argparse prints a usage block; one line with a pointer to --help reads better
        raise CLIError(f"{message} (see '{self.prog} --help')")


def compile_cache_dir() -> Path | None:
    """Where ``python -m rbjax`` keeps compiled programs between runs; ``None``: nowhere.

    ``$RBJAX_CACHE_DIR`` if set (``off`` turns the cache off), else
    ``$XDG_CACHE_HOME/rbjax/xla`` (``~/.cache/rbjax/xla``).
    """
    env = os.environ.get("RBJAX_CACHE_DIR")
    if env is not None:
        return None if env.strip().lower() in ("", "off", "0", "none") else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rbjax" / "xla"


def use_compile_cache() -> None:
    """Keep the fit's compiled programs on disk (jax's persistent compilation cache).

    Each ``python -m rbjax fit`` is a new process, and most of a short fit's time is
    making its program (seconds) rather than running it (milliseconds); from the
    second run with the same shapes on, the program is read back instead. Only for
    the command line's own process: a library does not change its caller's JAX
    configuration.
    """
    path = compile_cache_dir()
    if path is None:
        return
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:  # a read-only home: run without the cache, as uncached jax does
        return
    import jax

    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
