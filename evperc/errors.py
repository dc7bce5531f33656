"""User-facing error types.

Every mistake a user can make (a bad file, a bad option, a bad config) raises a subclass of
:class:`EvpercError`. The CLI turns it into one line on stderr and its ``exit_code``; no
traceback. Messages name the file, the place (topic, frame, feature, key) and, where there is
one, the fix. Exit codes (README): 0 success; 2 bad usage or bad input (click's own usage
errors exit 2 too); 1 a run of valid input that failed (:class:`WriteError`, and `evperc
batch` when a log failed); 130 Ctrl-C.
"""

from __future__ import annotations


class EvpercError(Exception):
    """Root of all errors caused by user input; its message is meant for the user."""

    exit_code = 2


class ConfigError(EvpercError):
    """The configuration file or a configuration value is wrong."""


class LogError(EvpercError):
    """The log file (MCAP) cannot be read or lacks what evperc needs."""


class TopicError(LogError):
    """No topic, or more than one candidate topic, fits what evperc needs."""


class PoseError(LogError):
    """Poses are missing, have gaps, go backwards, or the transform chain is broken."""


class MapError(EvpercError):
    """The map file cannot be read, is empty, or does not overlap the drive."""


class GeoreferenceError(EvpercError):
    """The log's poses cannot be placed in the working CRS (no origin, no GNSS)."""


class OutputError(EvpercError):
    """The output directory exists, is not writable, or is not an evperc output."""


class TruthError(EvpercError):
    """The ground truth given to `evaluate` is not of the run's drive (stamps, poses, grid)."""


class UsageError(EvpercError):
    """Command-line options that contradict each other or miss a required companion."""


class WriteError(EvpercError):
    """Valid input, but the run failed while writing its output (disk full, I/O error)."""

    exit_code = 1
