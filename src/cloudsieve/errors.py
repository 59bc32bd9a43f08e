"""The exceptions and warnings cloudsieve raises, all of them.

Root :class:`CloudsieveError`; each subclass also inherits the built-in a
caller expects (``ValueError``, ``FileNotFoundError``, ...). Messages name
the file and the problem. Warnings (``UserWarning``): :class:`ConvergenceWarning`,
:class:`IncompatibleCloudsWarning`.
"""

from __future__ import annotations

__all__ = [
    "CloudsieveError",
    "InputNotFoundError",
    "StoreNotFoundError",
    "InputFormatError",
    "UnknownFormatError",
    "CorruptInputError",
    "InvalidPointsError",
    "EmptyInputError",
    "DestinationExistsError",
    "SameSourceDestinationError",
    "DestinationNotWritableError",
    "PipelineError",
    "InputIsDirectoryError",
    "NotASubsetError",
    "IncompatibleCloudsError",
    "InvalidParameterError",
    "ResumeMismatchError",
    "InputNotReadableError",
    "SchedulerUnreachableError",
    "ArrayNotFoundError",
    "PartitionLayoutError",
    "MissingDependencyError",
    "TargetNotMetError",
    "MismatchedInputsError",
    "ConvergenceWarning",
    "IncompatibleCloudsWarning",
]


class CloudsieveError(Exception):
    """Root of every error cloudsieve raises on purpose.
    *advice* maps the options the message advises to their values (``{"overwrite": True}``, worded
    ``overwrite=True``; the command line rewrites those words as its own). Kept in ``__dict__``, so it survives
    pickling from dask workers."""

    def __init__(self, *args: object, advice: dict | None = None) -> None:
        super().__init__(*args)
        self.advice = dict(advice or {})


class InputNotFoundError(CloudsieveError, FileNotFoundError):
    """The input file does not exist."""


class StoreNotFoundError(CloudsieveError, FileNotFoundError):
    """The path is not a cloudsieve point store (or does not exist)."""


class InputFormatError(CloudsieveError, ValueError):
    """The input cannot be read as the format it claims (or was given)."""


class UnknownFormatError(InputFormatError):
    """No reader or writer is registered for the file's extension."""


class CorruptInputError(InputFormatError):
    """The file is truncated, corrupt, or its header disagrees with its data."""


class InvalidPointsError(InputFormatError):
    """Coordinates are NaN or infinite (refused unless asked to drop them)."""


class EmptyInputError(InputFormatError):
    """The input holds no points."""


class DestinationExistsError(CloudsieveError, FileExistsError):
    """The destination exists and overwriting was not asked for."""


class SameSourceDestinationError(CloudsieveError, ValueError):
    """The destination is the source: cloudsieve never overwrites its input."""


class DestinationNotWritableError(CloudsieveError, PermissionError):
    """The destination (or its folder) cannot be written."""


class PipelineError(CloudsieveError, ValueError):
    """A pipeline file is malformed."""


class InputIsDirectoryError(CloudsieveError, IsADirectoryError):
    """A directory was given where a file was expected."""


class NotASubsetError(CloudsieveError, ValueError):
    """The simplified cloud was claimed to be a subset of the original but is not."""


class IncompatibleCloudsError(CloudsieveError, ValueError):
    """Two clouds compared with each other differ in CRS or units (scale)."""


class InvalidParameterError(CloudsieveError, ValueError):
    """A parameter is out of range, or inconsistent with the input (shape, count)."""


class ResumeMismatchError(CloudsieveError, ValueError):
    """A work store holds a run with other parameters or another source (cannot resume it)."""


class InputNotReadableError(CloudsieveError, PermissionError):
    """The input exists but cannot be read (permissions)."""


class SchedulerUnreachableError(CloudsieveError, ConnectionError):
    """The dask.distributed scheduler address does not answer."""


class ArrayNotFoundError(CloudsieveError, KeyError):
    """A point store has no array of that name (or the name is a group)."""

    def __str__(self) -> str:  # the message, not KeyError's quoted repr of it
        return str(self.args[0]) if self.args else ""


class PartitionLayoutError(CloudsieveError, ValueError):
    """The store's partition is missing or in a layout this version does not read."""


class MissingDependencyError(CloudsieveError, ImportError):
    """An optional package needed for this input or evaluation is not installed."""


class TargetNotMetError(CloudsieveError, ValueError):
    """A ratio or count that could not be met, with ``strict`` (otherwise a logged warning)."""


class MismatchedInputsError(InputFormatError):
    """The files of one cloud (a glob, a directory, a list, a VPC) disagree: point format, attributes, CRS or scale."""


class ConvergenceWarning(UserWarning):
    """An iterative fit stopped at max_iter before its convergence test held."""


class IncompatibleCloudsWarning(UserWarning):
    """Clouds of different CRS or units compared anyway (``strict=False``); also logged, once (the CLI shows the log
    line only)."""
