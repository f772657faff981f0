"""One error family for fgen. Exit codes (documented in README):

0  success
1  bad input or a failed check (unreadable/corrupt file, missing channels, gaps, ...)
2  usage error (bad option or argument; click's own code)
3  output problem (unwritable folder, refusing to overwrite, writing into the input)
"""
from __future__ import annotations

import click

EXIT_OK = 0
EXIT_BAD_INPUT = 1
EXIT_USAGE = 2
EXIT_OUTPUT = 3


class FgenError(click.ClickException):
    """An error shown to the user as one line on stderr, with a documented exit code."""

    exit_code = EXIT_BAD_INPUT

    def __init__(self, message: str, *, file: str | None = None, frame: int | None = None,
                 channel: str | None = None):
        parts = []
        if file is not None:
            parts.append(f"file {file}")
        if frame is not None:
            parts.append(f"frame {frame}")
        if channel is not None:
            parts.append(f"channel {channel}")
        prefix = (", ".join(parts) + ": ") if parts else ""
        super().__init__(prefix + message)
        self.file, self.frame, self.channel = file, frame, channel
        self.detail = message  # the message without the file/frame/channel prefix

    def with_frame(self, frame: int) -> "FgenError":
        """The same error naming `frame` (unchanged when it already names one)."""
        if self.frame is not None:
            return self
        return type(self)(self.detail, file=self.file, frame=frame, channel=self.channel)


class InputError(FgenError):
    exit_code = EXIT_BAD_INPUT


class OutputError(FgenError):
    exit_code = EXIT_OUTPUT


class UsageError(FgenError):
    exit_code = EXIT_USAGE
