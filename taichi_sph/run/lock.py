"""One run per folder: `<run>/run.lock` names the process that writes the folder (pid, host, its start time).

`held(run_dir)` creates the lock exclusively (O_EXCL) when a run starts and removes it when the run ends, however it
ends. A lock whose process is gone is stale and taken over: on the same host, the pid is dead, or it now belongs to
another process (its start time in /proc differs). A live one refuses the run: `FolderInUse`, one line naming the
pid, exit 2. Readers use `live_holder` and `effective_status`: a summary.json that says `running` while no live
process holds the lock belongs to a run that died (killed, power cut), which `resume` continues and the study
executor reruns. A lock written on another host (a Ray cluster on a shared filesystem) cannot be checked from here:
it counts as alive, and the message says to remove the file once that run is known to be gone.
"""

from __future__ import annotations

import errno
import json
import os
import socket
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from taichi_sph.errors import DiskFull, FolderInUse

LOCK_NAME = "run.lock"


@dataclass(frozen=True)
class LockInfo:
    """What a lock file says: the process that holds the folder."""

    path: Path
    pid: int
    host: str
    start: int | None       # the process's start time (clock ticks since boot, /proc/<pid>/stat); None: unknown
    since: str = ""         # when the run took the lock (local time, for the message)

    def alive(self) -> bool:
        """Is the holder still running? Same host: its pid exists and started when the lock says; another
        host: assumed alive (cannot be checked from here)."""
        if self.host != socket.gethostname():
            return True
        if not pid_alive(self.pid):
            return False
        now = process_start(self.pid)
        return self.start is None or now is None or now == self.start

    def describe(self) -> str:
        where = "" if self.host == socket.gethostname() else f" on {self.host}"
        return f"pid {self.pid}{where}" + (f", since {self.since}" if self.since else "")


def pid_alive(pid: int) -> bool:
    """Does a process with this pid exist (signal 0: no signal sent)?"""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:
        return False
    return True


def process_start(pid: int) -> int | None:
    """The process's start time in clock ticks after boot (field 22 of /proc/<pid>/stat); None off Linux."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
        return int(text[text.rindex(")") + 2:].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def read_lock(run_dir: Path) -> LockInfo | None:
    """The folder's lock, None when there is none; an unreadable one (torn write) counts as stale (pid 0)."""
    path = Path(run_dir) / LOCK_NAME
    try:
        data = json.loads(path.read_text())
        return LockInfo(path, int(data["pid"]), str(data["host"]), data.get("start"), str(data.get("since", "")))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError):
        return LockInfo(path, 0, socket.gethostname(), None)


def live_holder(run_dir: Path) -> LockInfo | None:
    """The live process that holds the folder, None when it is free (no lock, or a stale one)."""
    lock = read_lock(run_dir)
    return lock if lock is not None and lock.pid > 0 and lock.alive() else None


def effective_status(run_dir: Path, status: str | None) -> str | None:
    """summary.json's status as it stands: `running` becomes `died` when no live process holds the folder."""
    if status == "running" and live_holder(run_dir) is None:
        return "died"
    return status


def in_use_message(run_dir: Path, lock: LockInfo) -> str:
    """The one line that refuses a second run into a live run's folder."""
    tail = (f"wait for it or stop it (kill {lock.pid})" if lock.host == socket.gethostname() else
            f"wait for it, or remove {lock.path} once that run is known to be gone")
    return f"{run_dir} is in use by a run still going ({lock.describe()}): {tail}"


def acquire(run_dir: Path) -> Path:
    """Take the folder's lock for this process (creating the folder), taking over a stale one; FolderInUse when
    a live process holds it."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / LOCK_NAME
    text = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "start": process_start(os.getpid()),
                       "since": time.strftime("%Y-%m-%d %H:%M:%S")})
    for _ in range(3):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            holder = live_holder(run_dir)
            if holder is not None:
                raise FolderInUse(in_use_message(run_dir, holder)) from None
            path.unlink(missing_ok=True)  # stale: its process is gone
            continue
        try:
            os.write(fd, text.encode())
        except OSError as e:
            os.close(fd)
            path.unlink(missing_ok=True)
            if e.errno in (errno.ENOSPC, errno.EDQUOT):
                raise DiskFull(f"no space left on device writing {path} (the run's lock, {len(text)} bytes): "
                               "free space first") from None
            raise
        os.close(fd)
        return path
    raise FolderInUse(f"{run_dir}: could not take {LOCK_NAME} (another run is taking it at the same time)")


def release(run_dir: Path) -> None:
    """Remove the folder's lock if this process holds it."""
    lock = read_lock(run_dir)
    if lock is not None and lock.pid == os.getpid() and lock.host == socket.gethostname():
        lock.path.unlink(missing_ok=True)


@contextmanager
def held(run_dir: Path | None) -> Iterator[None]:
    """The folder locked to this process for the duration (nothing when there is no folder). A folder this run
    created and left empty (a scene refused at start-up) is removed with the lock: no empty run folder behind."""
    if run_dir is None:
        yield
        return
    created = not Path(run_dir).exists()
    acquire(run_dir)
    try:
        yield
    finally:
        release(run_dir)
        if created:
            try:
                Path(run_dir).rmdir()  # only when empty
            except OSError:
                pass
