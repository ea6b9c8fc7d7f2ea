"""Domain errors raised by ``core``. Each carries a stable ``code`` and a message a user can act on.

``core`` never speaks HTTP: ``service/errors.py`` maps these classes to status codes.
"""

from __future__ import annotations

from typing import Any


class BodyspaceError(ValueError):
    """Base of all domain errors: bad input or a fit that cannot proceed."""

    code = "invalid_input"

    def __init__(self, message: str, **details: Any) -> None:
        super().__init__(message)
        self.message = message
        self.details = details


class InputFormatError(BodyspaceError):
    """A file is empty, truncated, malformed, of an unknown format or beyond the size limits."""

    code = "invalid_file"


class UnitsError(BodyspaceError):
    """Units or up-axis cannot be determined unambiguously, or the values are not a body."""

    code = "ambiguous_units"


class MarkerError(BodyspaceError):
    """Marker file problems: unknown names, non-finite values, too few usable markers."""

    code = "invalid_markers"


class FitError(BodyspaceError):
    """The registration cannot proceed with this input (e.g. markers far from the scan)."""

    code = "fit_failed"


class NotABodyError(FitError):
    """The scan cannot be a standing human body (size, proportions) in the frame it is read in."""

    code = "not_a_body"


class MeasurementError(BodyspaceError):
    """Tape measurements that cannot be used: unknown names, non-numbers, wrong units."""

    code = "invalid_measurements"
