"""One exception root for everything frontdiag reports to a user.

Library code raises these; only the CLI turns them into a one-line message and an exit code.
Each error builds its own message so callers never format user-facing text by hand.
"""

from __future__ import annotations

from pathlib import Path

# Exit codes, documented in the README and in `frontdiag --help`.
EXIT_OK = 0
EXIT_GATE = 1
EXIT_INPUT = 2
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130


def interrupt_on_signal(signum: int, frame: object) -> None:
    """A signal handler that ends the run the way Ctrl-C does (SIGTERM from a CI timeout or a
    supervisor): the pass catches the KeyboardInterrupt and keeps the frames analysed so far."""
    raise KeyboardInterrupt


class FrontdiagError(Exception):
    """Root of every error that is the user's input rather than a bug (exit code 2)."""

    exit_code = EXIT_INPUT
    hint: str | None = None

    def __init__(self, message: str, *, hint: str | None = None) -> None:
        super().__init__(message)
        if hint is not None:
            self.hint = hint

    def __reduce__(self) -> tuple[object, ...]:
        # subclasses take other arguments than their message: rebuild from message + attributes
        # (a fault met in a worker process crosses back to the caller pickled)
        return _rebuild, (type(self), str(self), dict(self.__dict__))


def _rebuild(cls: type[FrontdiagError], message: str, attrs: dict[str, object]) -> FrontdiagError:
    err = cls.__new__(cls)
    Exception.__init__(err, message)
    err.__dict__.update(attrs)
    return err


class RecordingError(FrontdiagError):
    """A recording is missing, unreadable, truncated or of an unknown container."""

    resumed = False
    """Damage met while streaming after which reading went on (a split recording's later
    parts): frames after the damage were analysed too."""

    def __init__(self, path: Path | str, problem: str, *, hint: str | None = None,
                 resumed: bool = False) -> None:
        self.path = Path(path)
        if resumed:
            self.resumed = True
        super().__init__(f"{path}: {problem}", hint=hint)


class TopicError(FrontdiagError):
    """A requested topic is absent, or the choice of topic is ambiguous."""

    def __init__(self, message: str, *, candidates: list[str] | None = None,
                 hint: str | None = None) -> None:
        self.candidates = candidates or []
        super().__init__(message, hint=hint)


class DecodeError(FrontdiagError):
    """One message could not be decoded. The reader skips and counts these."""

    def __init__(self, topic: str, field: str, problem: str) -> None:
        self.topic = topic
        self.field = field
        super().__init__(f"topic {topic}: field {field}: {problem}")


class ConfigError(FrontdiagError):
    """Invalid option, intrinsics, override file or target file."""


class RuleError(FrontdiagError):
    """A rules file is invalid: unknown metric, operator, check or condition."""

    def __init__(self, source: Path | str, problem: str) -> None:
        self.source = str(source)
        super().__init__(f"{source}: {problem}")


class OutputError(FrontdiagError):
    """An output location (--out, --junit, ...) cannot be written, or would overwrite an input."""

    def __init__(self, path: Path | str, problem: str, *, hint: str | None = None) -> None:
        self.path = Path(path)
        super().__init__(f"{path}: {problem}", hint=hint)


class OptionalDependencyError(FrontdiagError):
    """An optional heavy dependency (e.g. Open3D) is not installed or cannot load."""
