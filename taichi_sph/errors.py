"""The project's exception types: user errors become one line and an exit code in the CLI."""

from __future__ import annotations

EXIT_OK = 0
EXIT_USAGE = 2
EXIT_UNSTABLE = 3
EXIT_NO_SPACE = 4
EXIT_INTERRUPTED = 130


class SPHError(Exception):
    """Base class for errors that are the user's to fix (bad config, bad arguments, missing driver)."""

    exit_code: int = EXIT_USAGE


class ConfigError(SPHError):
    """A config file or override is invalid. The message names the file, the key and the allowed values."""

    def __init__(self, message: str, *, source: str | None = None, key: str | None = None) -> None:
        self.source = source
        self.key = key
        parts = []
        if source:
            parts.append(str(source))
        if key:
            parts.append(f"key '{key}'")
        prefix = ": ".join(parts)
        super().__init__(f"{prefix}: {message}" if prefix else message)


class UsageError(SPHError):
    """Bad command-line usage."""


class RenderUnavailable(SPHError):
    """Offscreen rendering cannot start (no Vulkan driver)."""


class PreflightError(SPHError):
    """A run refused before anything is allocated: not enough memory, or a set-up that cannot give a
    meaningful result (a severe a-priori check). `--force` runs it anyway."""


class FolderInUse(UsageError):
    """A run folder whose run is still going (its run.lock names a live process): a second run, a resume or a
    study case into it is refused, naming the pid (run/lock.py)."""


class DiskFull(SPHError):
    """The disk filled while a run wrote its folder: one line naming the path and the space needed, exit 4;
    temporary files are removed, summary.json says `failed` and the last checkpoint is kept (run/disk.py)."""

    exit_code: int = EXIT_NO_SPACE
