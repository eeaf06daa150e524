"""core.procs.exit_with_parent: a spawn pool's idle workers end when their parent is killed
outright (SIGKILL), where without it they wait on their call queue forever."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

# a parent that starts a two-worker spawn pool (with or without the watcher as initializer),
# makes sure both workers run, prints their PIDs and waits to be killed
PARENT = """
import os, sys, time
import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor
from grip_bench.core.procs import exit_with_parent

def pid_after(seconds):
    time.sleep(seconds)  # long enough that the two tasks run on two workers
    return os.getpid()

if __name__ == "__main__":
    init = exit_with_parent if sys.argv[1] == "watch" else None
    pool = ProcessPoolExecutor(2, mp_context=mp.get_context("spawn"), initializer=init)
    pids = {f.result() for f in [pool.submit(pid_after, 1.0) for _ in range(2)]}
    print(" ".join(map(str, sorted(pids))), flush=True)
    time.sleep(600)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie is dead, only not yet reaped
        return f.read().split(") ")[-1][0] != "Z"


def _orphans_after_kill(mode: str, tmp_path, wait: float) -> list[int]:
    script = tmp_path / "parent.py"
    script.write_text(PARENT)
    proc = subprocess.Popen([sys.executable, str(script), mode], stdout=subprocess.PIPE,
                            text=True)
    workers = [int(p) for p in proc.stdout.readline().split()]
    assert len(workers) == 2 and all(_alive(p) for p in workers)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline and any(_alive(p) for p in workers):
        time.sleep(0.2)
    left = [p for p in workers if _alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    return left


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_end_with_a_killed_parent(tmp_path):
    assert _orphans_after_kill("watch", tmp_path, wait=10.0) == []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_without_the_watch_the_workers_outlive_it(tmp_path):
    """The control: what the watch is for (a bare pool's workers are still there after three
    of the watch's polling periods)."""
    assert len(_orphans_after_kill("bare", tmp_path, wait=3.0)) == 2


def _spawned_children(pid: int) -> list[int]:
    """PIDs of ``pid``'s multiprocessing spawn children (its pool's workers)."""
    out = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                ppid = int(f.read().split(") ")[-1].split()[1])
            with open(f"/proc/{d}/cmdline", "rb") as f:
                cmd = f.read()
        except (FileNotFoundError, ProcessLookupError, IndexError, ValueError):
            continue
        if ppid == pid and b"spawn_main" in cmd:
            out.append(int(d))
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_synthgrab_workers_end_with_a_killed_generator(tmp_path):
    """The data pools carry the watch too (SynthGRAB here; the counterfactual split, capture
    noise and DDP ranks start theirs the same way): a generator killed outright while its
    two workers run leaves none behind."""
    proc = subprocess.Popen([sys.executable, "-m", "grip_bench", "data", "synth", "--profile",
                             "tiny", "--workers", "2", "--quiet", "--out", str(tmp_path / "d")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120.0
    workers: list[int] = []
    while time.monotonic() < deadline and len(workers) < 2 and proc.poll() is None:
        time.sleep(0.1)
        workers = _spawned_children(proc.pid)
    assert len(workers) == 2, "the generator's pool never started two workers"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and any(_alive(p) for p in workers):
        time.sleep(0.2)
    left = [p for p in workers if _alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert left == []
