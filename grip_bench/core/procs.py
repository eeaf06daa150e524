"""Worker processes that end with the process that started them.

A ``ProcessPoolExecutor`` worker waits on its call queue for the next task. When its parent
is killed outright (``kill -9``, the kernel's out-of-memory killer, a scheduler that kills
one PID) nothing ever closes that queue, so the worker waits forever: measured in s40, the
evaluation pool of a ``grip-bench run`` killed with SIGKILL left two idle workers holding
1.1 GB each. A pool initializer calls :func:`exit_with_parent` so that each worker watches
its parent and exits once it is gone.
"""

from __future__ import annotations

import os
import threading
import time

PARENT_POLL_SECONDS = 1.0  # how often a worker checks its parent (a sleeping thread: ~free)


def exit_with_parent(poll: float = PARENT_POLL_SECONDS) -> threading.Thread:
    """Start a daemon thread that ends this process (``os._exit(1)``, no clean-up: the
    parent that would collect its results is gone) as soon as its parent process is no
    longer the one that started it. Call it in the child, e.g. as a pool initializer.

    The parent is the one multiprocessing recorded when it started this process, not
    whichever parent it has by the time the initializer runs: a spawn worker imports its
    modules first (seconds), and a parent killed meanwhile has already handed it to init
    (measured in s41: SynthGRAB's workers outlived a generator killed while they started)."""
    import multiprocessing

    started_by = multiprocessing.parent_process()
    parent = os.getppid() if started_by is None else started_by.pid

    def watch() -> None:
        while True:
            if os.getppid() != parent:  # re-parented (to init or a subreaper): orphaned
                os._exit(1)
            time.sleep(poll)

    thread = threading.Thread(target=watch, name="exit-with-parent", daemon=True)
    thread.start()
    return thread
