"""bench/pipeline.py's process-tree sampling: the CPU time it books for a child process."""
import os
import subprocess
import sys
import time

from perceptual_uv.bench.pipeline import tree_cpu_ticks

BUSY_SECONDS = 0.5
# A child that spins until its own process_time() reaches BUSY_SECONDS, says so, then sleeps until killed.
SPIN = ("import sys, time\n"
        f"while time.process_time() < {BUSY_SECONDS}:\n"
        "    pass\n"
        "print('done', flush=True)\n"
        "time.sleep(60)\n")


def test_tree_cpu_ticks_counts_a_busy_child_and_not_a_sleeping_one():
    tick = os.sysconf("SC_CLK_TCK")
    child = subprocess.Popen([sys.executable, "-c", SPIN], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "done"
        ticks = tree_cpu_ticks(os.getpid())
        assert os.getpid() in ticks and child.pid in ticks
        # The kernel books user and system time in whole ticks: at least BUSY_SECONDS less one tick of each.
        assert ticks[child.pid] >= BUSY_SECONDS * tick - 2
        time.sleep(0.3)  # asleep: no tick more, but for the one the print may still round into
        assert tree_cpu_ticks(os.getpid())[child.pid] - ticks[child.pid] <= 1
    finally:
        child.kill()
        child.wait()
    assert child.pid not in tree_cpu_ticks(os.getpid())
