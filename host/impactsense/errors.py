"""Errors the package raises for bad input: each names the file and the field at fault."""

from __future__ import annotations


class ImpactSenseError(Exception):
    """Base class: the CLI prints these as one clear line and exits with status 2."""


class DataError(ImpactSenseError, ValueError):
    """A session folder, file or field is missing or invalid."""

    def __init__(self, path, field: str | None, problem: str):
        self.path = str(path)
        self.field = field
        self.problem = problem
        where = f"{self.path}" + (f" [{field}]" if field else "")
        super().__init__(f"{where}: {problem}")


class ConfigError(ImpactSenseError, ValueError):
    """A parameter or option has a value that makes no physical or practical sense."""
