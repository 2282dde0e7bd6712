"""The error and warning every model-file reader and writer raises."""

from __future__ import annotations

from seuwgpu.errors import InputError


class ModelFileError(InputError):
    """A model file that cannot be read or written; the message names the file and the problem."""


class NonFiniteWarning(UserWarning):
    """A loaded model holds NaN or Inf values (the message gives the count per field)."""
