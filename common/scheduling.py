"""Keeps a library from making this process's threads real-time.

SVT-AV1, opened by a process running as root, sets the calling thread to SCHED_FIFO at priority 99,
and the encoder's threads it then starts inherit it (libsvtav1 as PyAV's wheel ships it, measured
on Linux; imageio-ffmpeg's ffmpeg tries the same and fails, "Failed to set thread priority"). A
real-time thread that spins is never preempted by ordinary ones: a test suite whose process had
opened an encoder started headless chromium, which inherited the policy, spun on both cores and
left the suite's own deadline no time to run. Every thread that an encoder's opening turned
real-time goes back to what it was (new ones to the ordinary policy).
"""

import contextlib
import os
import sys
from collections.abc import Iterator

REAL_TIME = {getattr(os, name) for name in ("SCHED_FIFO", "SCHED_RR") if hasattr(os, name)}


def _policies() -> dict[int, tuple[int, int]]:
    """{thread id: (policy, priority)} of this process's threads; {} where Linux's /proc is not there."""
    out = {}
    with contextlib.suppress(OSError):
        for name in os.listdir("/proc/self/task"):
            with contextlib.suppress(OSError):  # a thread that ended meanwhile
                tid = int(name)
                out[tid] = (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
    return out


@contextlib.contextmanager
def kept_scheduling() -> Iterator[None]:
    """Within it, open what may make threads real-time; after it, those threads are as they were."""
    if not sys.platform.startswith("linux") or not REAL_TIME:
        yield
        return
    before = _policies()
    try:
        yield
    finally:
        for tid, (policy, _) in _policies().items():
            was, priority = before.get(tid, (os.SCHED_OTHER, 0))
            if policy in REAL_TIME and was not in REAL_TIME:
                with contextlib.suppress(OSError):
                    os.sched_setscheduler(tid, was, os.sched_param(priority))
