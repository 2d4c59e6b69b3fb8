"""Which process wrote a lock or a temporary, beyond its pid: pids are handed out again, by a long
uptime or by a reboot, and a lock naming a pid that another process now has would block every run.

A process is named by a token, "<pid>-<start time in clock ticks since boot>-<boot id>" (Linux:
/proc/<pid>/stat field 22 and /proc/sys/kernel/random/boot_id), or "<pid>" where the system says
neither. A token is alive while that very process runs: same boot, same pid, same start time.
"""

from __future__ import annotations

import os
import re
from pathlib import Path


def process_alive(pid: int) -> bool:
    """Whether process `pid` runs (a zombie, killed but not reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OverflowError:  # no such pid can exist
        return False
    try:  # a killed process not yet reaped by its parent is writing nothing
        return " Z " not in Path(f"/proc/{pid}/stat").read_text().split(")", 1)[1][:4]
    except (OSError, IndexError):
        return True


def _boot_id() -> str | None:
    """The first 8 hex digits of this boot's id (Linux), None where there is none."""
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip().replace("-", "")[:8] or None
    except OSError:
        return None


def _start_ticks(pid: int) -> int | None:
    """When process `pid` started, in clock ticks since boot (/proc/<pid>/stat field 22), or None."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return int(fields[19])  # fields[0] is field 3, the state
    except (OSError, IndexError, ValueError):
        return None


def _started_s(pid: int) -> float | None:
    """When process `pid` started, in seconds since the epoch (to about a second), or None."""
    ticks = _start_ticks(pid)
    try:
        stat = Path("/proc/stat").read_text()
        boot_s = next(int(line.split()[1]) for line in stat.splitlines() if line.startswith("btime "))
        return boot_s + ticks / os.sysconf("SC_CLK_TCK") if ticks is not None else None
    except (OSError, StopIteration, ValueError, IndexError):
        return None


#: A token: the pid, then (where the system says) the start time in clock ticks and the boot id.
TOKEN = r"\d+(?:-\d+-[0-9a-f]{8})?"
_TOKEN = re.compile(r"(\d+)(?:-(\d+)-([0-9a-f]{8}))?")
_mine: tuple[int, str] | None = None


def process_token() -> str:
    """This process's token (module doc)."""
    global _mine
    pid = os.getpid()
    if _mine is None or _mine[0] != pid:  # made again in a forked child
        ticks, boot = _start_ticks(pid), _boot_id()
        _mine = (pid, f"{pid}-{ticks}-{boot}" if ticks is not None and boot else str(pid))
    return _mine[1]


def token_pid(token: str) -> int | None:
    """The pid a token names; None where `token` is no token."""
    m = _TOKEN.fullmatch(token.strip())
    return int(m.group(1)) if m else None


def token_alive(token: str, written_s: float | None = None) -> bool:
    """Whether the process that `token` names still runs (not another one that has its pid since).

    An older token holds only a pid: it counts as alive while that pid runs a process that started
    before `written_s` (when the lock or temporary was last written), so a reboot frees it too."""
    m = _TOKEN.fullmatch(token.strip())
    if m is None or not process_alive(int(m.group(1))):
        return False
    pid = int(m.group(1))
    if m.group(2) is not None:
        boot, ticks = _boot_id(), _start_ticks(pid)
        return (boot is None or boot == m.group(3)) and (ticks is None or ticks == int(m.group(2)))
    started_s = _started_s(pid)
    return written_s is None or started_s is None or started_s <= written_s + 1.0  # btime is whole seconds
