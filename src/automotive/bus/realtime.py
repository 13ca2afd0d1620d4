"""Real-time settings of an application's process, as real-time Linux applications set them: a modest real-time
priority for the thread that takes the samples and for Cyclone's receive thread, and the process's memory locked.

- ``config.realtimePriority`` (0: off, the default; 1..49): the application's own thread (the one that waits on its
  WaitSet, takes and writes) runs under SCHED_FIFO at this priority once its set-up is done, and so does Cyclone's
  receive thread ("recv", set through Cyclone's configuration, :meth:`automotive.bus.network.NetworkConfig.elements`).
  Every other thread stays at the default policy: Cyclone's housekeeping threads and the application's own (status
  line, diagnostics) are created with SCHED_RESET_ON_FORK in force or before the priority is set. On a busy machine
  these two threads then no longer wait for a core behind other processes' work (docs/measurements/alert-latency.md).
  At most 49: below the kernel's interrupt threads (SCHED_FIFO 50), so that the network's own work is never starved.
  Only for applications that sleep between samples: a thread at a real-time priority that spins (a camera or LiDAR
  loop, a busy handler) takes a core from everything else on the host.
- ``config.lockMemory`` (false by default): ``mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)``: every page the
  process touches stays in RAM, so a process that wakes after 100 ms of idleness finds its pages where it left them
  (the kernel pages cold pages out even with plenty free). MCL_ONFAULT locks pages as they are first touched, not the
  whole of every mapping (thread stacks, arenas, shared-memory mappings): the resident memory stays what it was.

Both need permission: the priority root or CAP_SYS_NICE (or an RLIMIT_RTPRIO as high), the lock root or CAP_IPC_LOCK
(or an unlimited RLIMIT_MEMLOCK: under a finite one MCL_FUTURE would make later allocations fail once the limit is
reached, so it is not tried). Where the process lacks it, the application says so in one line and runs without.
"""

from __future__ import annotations

import ctypes
import errno
import os
import resource
from dataclasses import dataclass

from automotive.bus.properties import Properties

PRIORITY_KEY = "config.realtimePriority"
LOCK_MEMORY_KEY = "config.lockMemory"
MAX_PRIORITY = 49  # the kernel's threaded interrupt handlers run at SCHED_FIFO 50
_CAP_IPC_LOCK = 14
_MCL_CURRENT, _MCL_FUTURE, _MCL_ONFAULT = 1, 2, 4


@dataclass(frozen=True)
class RealtimeSettings:
    priority: int = 0
    lock_memory: bool = False


def read_settings(props: Properties) -> RealtimeSettings:
    return RealtimeSettings(props.get_int(PRIORITY_KEY, 0, minimum=0, maximum=MAX_PRIORITY),
                            props.get_bool(LOCK_MEMORY_KEY, False))


def priority_problem(priority: int) -> str | None:
    """Why this process may not run threads at SCHED_FIFO ``priority`` (None: it may). Tried on the calling thread,
    which goes back to the default policy at once: the kernel's verdict, whatever grants it (root, CAP_SYS_NICE,
    RLIMIT_RTPRIO, a cgroup's real-time budget)."""
    if not hasattr(os, "sched_setscheduler"):  # Linux's; elsewhere not offered
        return f"{PRIORITY_KEY}={priority} not applied: not supported on this system; running at the default priority"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        return (f"{PRIORITY_KEY}={priority} not applied: not permitted (needs root, CAP_SYS_NICE or an RLIMIT_RTPRIO "
                f"of at least {priority}); running at the default priority")
    except OSError as error:
        return f"{PRIORITY_KEY}={priority} not applied: {error.strerror}; running at the default priority"
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return None


def raise_this_thread(priority: int) -> None:
    """The calling thread at SCHED_FIFO ``priority``; threads it creates from now on start at the default policy."""
    os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))


def _has_capability(bit: int) -> bool:
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> bit & 1)
    except (OSError, ValueError):
        pass
    return False


def lock_memory() -> str | None:
    """Lock the process's pages in RAM (see the module's docstring); None when done, else the one line saying why
    not."""
    if not hasattr(resource, "RLIMIT_MEMLOCK"):
        return f"{LOCK_MEMORY_KEY}=true not applied: not supported on this system; memory not locked"
    limit = resource.getrlimit(resource.RLIMIT_MEMLOCK)[0]
    if not _has_capability(_CAP_IPC_LOCK) and limit != resource.RLIM_INFINITY:
        return (f"{LOCK_MEMORY_KEY}=true not applied: not permitted (needs root, CAP_IPC_LOCK or an unlimited "
                f"RLIMIT_MEMLOCK; the limit is {limit // 1024} KiB); memory not locked")
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE | _MCL_ONFAULT) != 0:
        code = ctypes.get_errno()
        return f"{LOCK_MEMORY_KEY}=true not applied: mlockall failed ({errno.errorcode.get(code, code)}: " \
               f"{os.strerror(code)}); memory not locked"
    return None
