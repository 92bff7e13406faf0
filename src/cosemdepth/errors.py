"""User-facing errors.

Every error a user can cause by bad input (a file, an argument, a config value) is raised as a subclass of
:class:`CosemdepthError` with a message that names the offending file or argument and what is wrong with it.
The command-line interface prints these messages without a traceback and exits with status 2.
"""

from __future__ import annotations


class CosemdepthError(Exception):
    """Base class of the errors caused by bad input, with a message meant for the user."""


class CheckpointError(CosemdepthError):
    """A checkpoint (TensorFlow or our own format) is missing, corrupt, truncated or foreign."""


class DatasetError(CosemdepthError):
    """A dataset file is missing or malformed (image, label, CSV, pose file, HDF5 record)."""


class ConfigError(CosemdepthError):
    """A configuration value or command-line argument is invalid."""


class NonFiniteOutputError(CosemdepthError):
    """A model produced NaN or inf for a frame (broken weights or input); the run stops instead of writing them."""
