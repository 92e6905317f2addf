"""Exceptions shared by every stage of spotpde.

``CaseError`` is raised for invalid input (a case file, a parameter out of range):
the command line prints its lines and exits with status 2. ``NumericalError`` is
raised when a solver detects a blow-up (NaN, negative probability, lost mass): the
command line prints it and exits with status 1, and no result file is written.
"""

from __future__ import annotations


class CaseError(ValueError):
    """An invalid case: one message line per problem, each naming the dotted key.

    Args:
        problems: lines such as ``"spots.b: must be > 0, got -1.0"``.
    """

    def __init__(self, problems: str | list[str]):
        if isinstance(problems, str):
            problems = [problems]
        self.problems: list[str] = list(problems)
        super().__init__("\n".join(self.problems))


class NumericalError(RuntimeError):
    """A solver stopped because its result would be wrong (NaN, P < 0, mass lost)."""


class WriteError(OSError):
    """A result could not be written (disk full, file-size limit, I/O error); the
    temporary file of the atomic write has been removed and an existing target left
    untouched. The command line prints it and exits with status 1."""
