"""The project's own errors: every failure a user can cause or fix is one of these, and the
command line prints it as one line (`seuwgpu CMD: error: ...`, exit status 2) with no traceback.

Anything else escaping a command is a bug in seuwgpu, not in its input. The input errors stay
ValueErrors so that callers that catch ValueError (and older tests) keep working.
"""

from __future__ import annotations

import importlib


class SeuwgpuError(Exception):
    """Base of every error seuwgpu raises on purpose; the message names the input and the problem."""


class InputError(SeuwgpuError, ValueError):
    """Bad input: a file, spec value, camera or argument that cannot be used as given."""


class RunInUse(SeuwgpuError):
    """Another process holds the run directory (its lock file is taken)."""


class TooBig(SeuwgpuError):
    """The job would not fit the host's or the device's memory; the message says what would fit."""


class MissingExtra(SeuwgpuError, ImportError):
    """An optional analysis needs a library the plain install leaves out; `remedy` is the pip
    line of the extra that brings it (the report lists the analysis as skipped with it)."""

    def __init__(self, reason: str, remedy: str):
        super().__init__(f"{reason}: {remedy}")
        self.reason, self.remedy = reason, remedy


# import name -> distribution name, for the messages
_DISTRIBUTIONS = {"scipy": "scipy", "sklearn": "scikit-learn", "skimage": "scikit-image"}


def require(module: str, extra: str, what: str):
    """`module`, imported; MissingExtra naming `what` needs it and the extra to install otherwise."""
    try:
        return importlib.import_module(module)
    except ImportError:
        top = module.split(".")[0]
        reason = f"{what} needs {_DISTRIBUTIONS.get(top, top)}, which the plain install leaves out"
        raise MissingExtra(reason, f"pip install 'seuwgpu[{extra}]'") from None


class Terminated(KeyboardInterrupt):
    """SIGTERM (`kill`, a batch scheduler's pre-emption or time limit) raised where the process is,
    so that it stops as Ctrl-C stops it: parts and partial records written, locks released."""

    received = False  # set by the handler: code that re-raises interrupts as plain ones (Ray) loses the type
