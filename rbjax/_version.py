"""The version of rbjax: its one source (pyproject.toml reads it with setuptools' ``attr:``)."""

__version__ = "0.1.0"
