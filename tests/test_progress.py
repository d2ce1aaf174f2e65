"""Whole-run progress: fraction from stage shares, time left, and the CLI's progress lines."""
import pytest

from perceptual_uv.core.progress import RunProgress, StageParts, format_seconds


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_fraction_adds_earlier_shares_and_the_current_stage_part():
    clock = FakeClock()
    run = RunProgress({"read": 1, "triangle": 6, "mesh": 3}, clock=clock)
    assert run.update("read", 0, 1) == (0.0, None)
    clock.now += 10
    fraction, left = run.update("triangle", 3, 6)  # 0.1 + 0.6 * 0.5 = 0.4 after 10 s
    assert fraction == pytest.approx(0.4)
    assert left == pytest.approx(10 * 0.6 / 0.4)  # 15 s
    clock.now += 20
    fraction, left = run.update("mesh", 1, 1)
    assert fraction == pytest.approx(1.0) and left == pytest.approx(0.0)


def test_fraction_never_goes_back_and_unknown_stages_keep_it():
    clock = FakeClock()
    run = RunProgress({"a": 1, "b": 1}, clock=clock)
    clock.now += 4
    assert run.update("b", 1, 2)[0] == pytest.approx(0.75)
    assert run.update("b", 0, 5)[0] == pytest.approx(0.75)  # a stage restarting its count
    assert run.update("a", 1, 1)[0] == pytest.approx(0.75)
    assert run.update("elsewhere", 0, 1)[0] == pytest.approx(0.75)
    assert run.update("b", 2, 0)[0] == pytest.approx(1.0)  # no units: the stage counts as done


def test_work_of_an_earlier_run_moves_the_bar_but_not_the_rate():
    clock = FakeClock()
    run = RunProgress({"read": 1, "triangle": 6, "mesh": 3}, clock=clock)
    clock.now += 10
    run.update("read", 1, 1)  # 0.1 of the run in 10 s
    run.skip("triangle", 50, 100)  # half the stage kept by a run that was stopped
    fraction, left = run.update("triangle", 50, 100)
    assert fraction == pytest.approx(0.4)
    assert left == pytest.approx(10 * 0.6 / 0.1)  # this run: 0.1 in 10 s, 0.6 left
    clock.now += 30
    fraction, left = run.update("triangle", 75, 100)  # 0.1 + 0.15 done by this run in 40 s
    assert fraction == pytest.approx(0.55)
    assert left == pytest.approx(40 * 0.45 / 0.25)  # 72 s (0.45 / 0.55 of 40 s without the skip: 33 s)


def test_no_time_left_before_a_hundredth_of_the_run():
    clock = FakeClock()
    run = RunProgress({"a": 1}, clock=clock)
    clock.now += 1
    assert run.update("a", 1, 200)[1] is None
    assert run.update("a", 2, 200)[1] == pytest.approx(1 * 0.99 / 0.01)


def test_stage_parts_report_each_part_as_its_share_of_the_stage():
    clock = FakeClock()
    steps = []
    parts = StageParts("mesh", {"short": 1, "long": 3}, lambda *step: steps.append(step) or step, clock=clock)
    clock.now += 10
    parts.step("short", 1, 2, "Short")  # 0.25 * 1/2 of the stage in 10 s: 0.875 of it left, 70 s
    clock.now += 10
    parts.step("short", 2, 2, "Short")  # 0.25 in 20 s: 60 s left
    parts.step("long", 0, 30, "Long")  # a part starting does not move the bar back
    clock.now += 40
    parts.step("long", 10, 30, "Long")  # 0.25 + 0.75 * 1/3 = 0.5 in 60 s: 60 s left
    assert steps == [("mesh", 125, 1000, "Short: 1/2, 1 min 10 s left in this stage"),
                     ("mesh", 250, 1000, "Short: 2/2, 1 min 00 s left in this stage"),
                     ("mesh", 250, 1000, "Long: 0/30, 1 min 00 s left in this stage"),
                     ("mesh", 500, 1000, "Long: 10/30, 1 min 00 s left in this stage")]


def test_stage_parts_relay_a_part_and_return_its_value():
    clock = FakeClock()
    parts = StageParts("mesh", {"a": 1, "b": 1}, lambda *step: step, clock=clock, started=clock.now - 5)

    def counting():
        yield 1, 4
        yield 4, 4
        return "value"

    relay = parts.relay(counting(), "b", "B")
    assert next(relay) == ("mesh", 625, 1000, "B: 1/4, 3 s left in this stage")  # 0.625 in 5 s
    assert next(relay) == ("mesh", 1000, 1000, "B: 4/4, 0 s left in this stage")
    with pytest.raises(StopIteration) as finished:
        next(relay)
    assert finished.value.value == "value"


def test_bad_shares_are_refused():
    for shares in ({}, {"a": 0}, {"a": -1, "b": 2}):
        with pytest.raises(ValueError):
            RunProgress(shares)


@pytest.mark.parametrize("seconds, text",
                         [(0.4, "0 s"), (59.4, "59 s"), (65, "1 min 05 s"), (3600 + 125, "1 h 02 min")])
def test_format_seconds(seconds, text):
    assert format_seconds(seconds) == text


def test_cli_lines_at_stage_changes_and_during_a_long_step(capsys):
    import time

    from perceptual_uv.bridge.batch import _ProgressLines
    from perceptual_uv.bridge.pipeline import Progress

    with _ProgressLines(interval=0.2) as lines:
        lines.update(Progress("triangle", 1, 100, "Triangle-wise optimization: 1/100", 0.05, 200.0))
        for done in range(2, 50):  # fast steps within one stage: no new line before the interval
            lines.update(Progress("triangle", done, 100, f"Triangle-wise optimization: {done}/100", 0.05, 200.0))
        lines.update(Progress("pack", 0, 1, "Packing islands", 0.8, 30.0))
        time.sleep(0.75)  # one long step: the thread keeps printing
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "[triangle] Triangle-wise optimization: 1/100 · 5% of the run, 3 min 20 s left"
    assert err[1] == "[pack] Packing islands · 80% of the run, 30 s left"
    heartbeat = err[2:]
    assert 2 <= len(heartbeat) <= 4
    assert all(line.startswith("[pack] Packing islands · 80% of the run, 30 s left (this step running for ")
               for line in heartbeat)


def test_cli_lines_at_the_first_step_of_each_part_of_a_stage(capsys):
    from perceptual_uv.bridge.batch import _ProgressLines
    from perceptual_uv.bridge.pipeline import Progress

    with _ProgressLines(interval=60.0) as lines:
        for done in range(3):
            lines.update(Progress("mesh", 10 + done, 1000, f"Measuring the texture's signal stretch: {done}/2", 0.8,
                                  9.0))
        for done in range(3):
            lines.update(Progress("mesh", 400 + done, 1000, f"Mesh-wise fit, with and without rotation targets: "
                                  f"{done}/202", 0.85, 8.0))
        prefix = "Texture 2 of 2 ('wood: dark' on Shelf): "  # a job of several textures names each run's
        for part in ("Finding the textured triangles", "Setting the mesh-wise fit's targets"):
            for done in range(2):
                lines.update(Progress("mesh", 500 + done, 1000, f"{prefix}{part}: {done}/2, 3 s left in this stage",
                                      0.9, 2.0))
    err = capsys.readouterr().err.splitlines()
    assert err == ["[mesh] Measuring the texture's signal stretch: 0/2 · 80% of the run, 9 s left",
                   "[mesh] Mesh-wise fit, with and without rotation targets: 0/202 · 85% of the run, 8 s left",
                   f"[mesh] {prefix}Finding the textured triangles: 0/2, 3 s left in this stage · 90% of the run, 2 s "
                   "left",
                   f"[mesh] {prefix}Setting the mesh-wise fit's targets: 0/2, 3 s left in this stage · 90% of the run, "
                   "2 s left"]


def test_cli_prints_a_stage_end_repeated_by_its_last_steps_once(capsys):
    from perceptual_uv.bridge.batch import _ProgressLines
    from perceptual_uv.bridge.pipeline import Progress

    with _ProgressLines(interval=60.0) as lines:
        lines.update(Progress("triangle", 0, 8, "Triangle-wise optimization: 0/8", 0.01, None))
        for _ in range(4):  # the workers stopping: the same end again at each step
            lines.update(Progress("triangle", 8, 8, "Triangle-wise optimization: 8/8", 0.75, 7.0))
    assert capsys.readouterr().err.splitlines() == [
        "[triangle] Triangle-wise optimization: 0/8 · 1% of the run",
        "[triangle] Triangle-wise optimization: 8/8 · 75% of the run, 7 s left"]


def test_cli_heartbeat_lines_name_no_long_step_while_the_pipeline_yields(capsys):
    import time

    from perceptual_uv.bridge.batch import _ProgressLines
    from perceptual_uv.bridge.pipeline import Progress

    with _ProgressLines(interval=1.0) as lines:
        end = time.monotonic() + 2.5
        while time.monotonic() < end:  # a stage whose generator yields every 10 ms (waiting for its workers)
            lines.update(Progress("triangle", 5, 100, "Triangle-wise optimization: 5/100", 0.05, 200.0))
            time.sleep(0.01)
    err = capsys.readouterr().err.splitlines()
    assert len(err) >= 3  # the first line, then one at least every second
    assert not any("running for" in line for line in err)


def test_report_while_waiting_yields_the_progress_for_each_wait_and_returns_the_value():
    from perceptual_uv.core.progress import report_while_waiting, run_generator

    def waiting():
        yield None
        yield None
        return 7

    steps = []
    assert run_generator(report_while_waiting(waiting(), ("read", 2)), lambda *step: steps.append(step)) == 7
    assert steps == [("read", 2), ("read", 2)]  # run_generator unpacks each yielded item


def test_a_closed_waiter_leaves_its_function_running_and_wait_for_threads_waits_for_it():
    import threading

    from perceptual_uv.core.progress import InThread, wait_for_threads

    release = threading.Event()
    running = InThread(release.wait, 10.0, interval=0.01)
    waiting = running.wait()
    assert next(waiting) is None  # the function blocks: the generator hands control back
    waiting.close()  # a cancel: nothing waits for the function here
    assert not wait_for_threads(timeout=0.05)
    release.set()
    assert wait_for_threads(timeout=10.0)
    assert running.join() is True  # Event.wait's value


def test_a_signal_raised_while_waiting_does_not_mark_the_thread_finished():
    import signal
    import threading

    from perceptual_uv.core.progress import InThread, wait_for_threads

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers run in the main thread only")

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    release = threading.Event()
    previous = signal.signal(signal.SIGALRM, interrupt)
    try:
        running = InThread(release.wait, 10.0, interval=5.0)  # the main thread sits in one long wait
        signal.setitimer(signal.ITIMER_REAL, 0.05)
        with pytest.raises(KeyboardInterrupt):
            for _ in running.wait():
                pass
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    # Waiting in Thread.join(timeout) here, Python 3.11 marked the running thread stopped: nothing could wait for it.
    assert running._thread.is_alive()
    assert not wait_for_threads(timeout=0.05)
    release.set()
    assert wait_for_threads(timeout=10.0)
    running._thread.join(10.0)
    assert not running._thread.is_alive()
