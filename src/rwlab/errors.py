"""The exception hierarchy: one base class, one subclass per kind of failure."""

from __future__ import annotations


class RwlabError(Exception):
    """Base class of every error rwlab raises on purpose."""


class DataError(RwlabError, ValueError):
    """Input data are unusable: NaN/Inf, wrong shapes, missing sample time, too short."""


class EstimationError(RwlabError):
    """An estimator cannot produce a model from the data and orders it was given."""


class ModelError(RwlabError, ValueError):
    """A model is malformed, or an operation is undefined for it."""


class ConfigError(RwlabError, ValueError):
    """A configuration value or option is invalid."""


class FileFormatError(RwlabError):
    """A file is truncated, of the wrong kind, or lacks required fields."""


class WheelTimeout(RwlabError, TimeoutError):
    """The wheel did not answer within the time allowed."""


class WheelFault(RwlabError):
    """The wheel reports a latched fault; clear it with ``WheelClient.clear_fault()``.

    Parameters
    ----------
    message : str
        What happened, and what to do.
    faults : int
        The wheel's latched fault bits (``rwlab.wheel.physics.Fault``).
    """

    def __init__(self, message: str, faults: int = 0) -> None:
        super().__init__(message)
        self.faults = faults


class WheelCommandError(RwlabError, ValueError):
    """A command outside the wheel's limits, refused before it was sent."""


class ProtocolError(RwlabError):
    """A frame that is not a valid wheel message (bad length, checksum or value)."""


class SlipError(ProtocolError):
    """An NSP frame whose SLIP framing is wrong (FESC followed by neither TFEND nor TFESC)."""


class DesignError(RwlabError, ValueError):
    """Weights or a plant for which the requested design does not exist."""


class MissingDependencyError(RwlabError, ImportError):
    """An optional dependency is not installed; the message names the extra to install."""


class RecordGapError(DataError):
    """A record has gaps in its telemetry longer than the caller accepts."""


class RwlabWarning(UserWarning):
    """A result rwlab returns but does not vouch for, e.g. an estimator that stopped early."""


class RecordBusyError(RwlabError):
    """Another run is writing the same record."""


class WheelConflict(RwlabError):
    """Two sources answer under one wheel's node id: their telemetry cannot be told apart."""


class HilStopped(RwlabError):
    """A hardware-in-the-loop run stopped before its end (the wheels idled, the record closed).

    Parameters
    ----------
    message : str
        What stopped it.
    interrupted : bool
        True when Ctrl-C, SIGTERM or SIGHUP stopped it (the CLI then exits with status
        130, as every other command does).
    """

    def __init__(self, message: str, *, interrupted: bool = False) -> None:
        super().__init__(message)
        self.interrupted = interrupted


class OutputBusyError(RwlabError):
    """Another run is writing the same output folder."""


class LostWorkerError(RwlabError):
    """A campaign's batch lost its worker more often than it is retried."""


class FormatWarning(RwlabWarning):
    """A file in an older format was read; the message says how to convert it."""


class NoModelFitsError(EstimationError):
    """An identification study ran, but even its best model fits the validation data worse
    than their mean (a negative fit %). The study's files were written; ``study`` holds
    its numbers and ``paths`` its files (``rwlab identify`` exits 1)."""

    def __init__(self, message: str, *, study: dict | None = None, paths: dict | None = None):
        super().__init__(message)
        self.study = study
        self.paths = paths


class RecordDamagedError(FileFormatError):
    """A record's bytes are damaged (a CRC mismatch, an unreadable record, a cut copy).

    Parameters
    ----------
    message : str
        Where the damage is and what is still readable.
    offset : int
        Byte offset of the first damaged record in the file.
    readable_s : float
        Seconds of the experiment before the damage (0 when none).
    """

    def __init__(self, message: str, offset: int = 0, readable_s: float = 0.0) -> None:
        super().__init__(message)
        self.offset = offset
        self.readable_s = readable_s
