"""Exceptions of the capture subsystem; each message names the problem and the fix."""

from __future__ import annotations


class CaptureError(Exception):
    """Base class of capture errors."""


class RigError(CaptureError):
    """The rig refused a command, misbehaved, or the link failed beyond recovery."""


class PortNotFound(RigError):
    """The serial port does not exist."""


class PortBusy(RigError):
    """Another process holds the serial port (it is opened exclusively)."""


class RigTimeout(RigError):
    """The rig did not answer in time."""


class ProtocolVersionError(RigError):
    """The rig speaks another protocol version than this host."""


class CaptureFileError(CaptureError):
    """A capture file is malformed, incomplete, locked, or does not match the requested scan."""
