"""bench/pipeline.py's process-tree sampling: the CPU time it books for a child process."""
import os
import subprocess
import sys
import time

from perceptual_uv.bench.pipeline import tree_cpu_ticks, tree_memory

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


def test_tree_memory_reads_the_proportional_size_only_when_asked():
    page = os.sysconf("SC_PAGE_SIZE")
    own, _, _ = tree_memory(os.getpid(), proportional=False)
    assert own[0] == own[1]  # both the resident size
    with open(f"/proc/{os.getpid()}/statm") as statm:
        resident = int(statm.read().split()[1]) * page
    assert abs(own[0] - resident) <= 64 * page  # read a moment apart
    own, _, _ = tree_memory(os.getpid())
    if os.path.exists(f"/proc/{os.getpid()}/smaps_rollup"):
        # The proportional size splits shared pages between their processes: never above the resident size (the
        # two are read a moment apart).
        assert 0 < own[1] <= own[0] + 64 * page
