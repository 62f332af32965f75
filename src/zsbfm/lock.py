"""One writer per run directory.

A run holds `<run dir>/.lock` while it trains (zsbfm.train, zsbfm.sweep): a small JSON file
with the holder's host and pid, created atomically (O_EXCL) and removed when the run ends,
however it ends short of SIGKILL. A second process that wants the directory gets
`RunLocked`, a one-line error naming the holder. A lock left by a process that is gone
(its pid no longer runs on this host: a SIGKILL, a crash of the machine) is taken over with
a warning; a lock of another host cannot be checked from here and is never taken over.
"""

from __future__ import annotations

import json
import os
import socket
import sys

LOCK_NAME = ".lock"


class RunLocked(RuntimeError):
    """The run directory is held by another process."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _holder(path: str) -> dict | None:
    try:
        with open(path) as f:
            return json.load(f)
    except (FileNotFoundError, json.JSONDecodeError):  # released, or being written right now
        return None


class RunDirLock:
    """`with RunDirLock(run_dir):` holds run_dir (created if needed) for this process."""

    def __init__(self, run_dir: str):
        self.run_dir = os.path.abspath(run_dir)
        self.path = os.path.join(self.run_dir, LOCK_NAME)
        self.me = {"host": socket.gethostname(), "pid": os.getpid()}
        self.held = False

    def acquire(self) -> "RunDirLock":
        os.makedirs(self.run_dir, exist_ok=True)
        for _ in range(3):  # a stale lock is moved away once; a race may cost another try
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = _holder(self.path)
                if holder is None:
                    continue
                if holder.get("host") == self.me["host"] and not _alive(int(holder.get("pid", -1))):
                    print(f"warning: taking over the lock of {self.run_dir} from pid {holder.get('pid')} "
                          f"on {holder.get('host')}, which no longer runs", file=sys.stderr)
                    stale = f"{self.path}.stale-{os.getpid()}"
                    try:  # atomic: of two processes taking over, one moves it
                        os.replace(self.path, stale)
                        os.remove(stale)
                    except FileNotFoundError:
                        pass
                    continue
                raise RunLocked(f"{self.run_dir} is in use by pid {holder.get('pid')} on {holder.get('host')} "
                                f"(lock file {self.path}): wait for that run to end, or choose another "
                                "--name; delete the lock file only if that process is gone") from None
            with os.fdopen(fd, "w") as f:
                json.dump(self.me, f)
            self.held = True
            return self
        raise RunLocked(f"{self.run_dir}: could not take its lock file {self.path} (another process keeps taking it)")

    def release(self) -> None:
        if self.held and _holder(self.path) == self.me:
            os.remove(self.path)
        self.held = False

    def __enter__(self) -> "RunDirLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
