"""Shape-space domain errors (``core.errors.BodyspaceError`` subclasses)."""

from __future__ import annotations

from core.errors import BodyspaceError


class OutOfRangeError(BodyspaceError):
    """A requested feature or PCA weight lies outside what the shape model supports.

    ``details`` holds ``feature``, ``value`` and ``supported`` (a ``[low, high]`` pair) when a
    single feature is at fault.
    """

    code = "out_of_range"


class ModelFormatError(BodyspaceError):
    """A shape-model file or a training folder cannot be read or is inconsistent."""

    code = "invalid_model"
