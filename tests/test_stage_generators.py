"""Stages as generators that hand control back while worker processes compute (no long step in Blender)."""
import multiprocessing
import threading
import time

import numpy as np

from perceptual_uv.core import loss_passes as lp
from perceptual_uv.core import trianglewise as tw
from perceptual_uv.core import worker_pool
from perceptual_uv.core.chartfit import fit_charts, iter_fit_charts
from perceptual_uv.core.meshwise import iter_solve_meshwise, solve_meshwise
from perceptual_uv.core.progress import run_generator

from meshes import grid_mesh as _grid_mesh  # noqa: E402  (tests/ is on sys.path under pytest)

SIZE = 64


def grid_mesh(cells=2):
    return _grid_mesh(cells)


def texture():
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    return 0.5 + 0.25 * np.sin(2 * np.pi * x / 9.0) * np.cos(2 * np.pi * y / 13.0)


def test_iter_losses_yield_face_counts_and_return_the_losses():
    V, F, uv = grid_mesh()
    new_uv = 0.5 + 0.6 * (uv - 0.5)
    progress = []
    losses = run_generator(lp.iter_losses_at(V, F, uv, texture(), new_uv, workers=1, chunk_size=3),
                           lambda *step: progress.append(step))
    # the start, the workers' shared state (one step between the view sizes and the one-rings), then each chunk
    # (3, 3 and 2 faces, in the chunks' order)
    assert progress[:2] == [(0, 8), (0, 8)] and progress[-1] == (8, 8) and len(progress) == 5
    assert sorted(b[0] - a[0] for a, b in zip(progress[1:], progress[2:])) == [2, 3, 3]
    np.testing.assert_array_equal(losses, lp.losses_at(V, F, uv, texture(), new_uv))
    params = np.tile([0.0, 0.7, 0.6, 0.0], (8, 1))
    progress = []
    losses = run_generator(lp.iter_losses_of(V, F, uv, texture(), params, workers=1, chunk_size=4),
                           lambda *step: progress.append(step))
    assert progress == [(0, 8), (0, 8), (4, 8), (8, 8)]
    np.testing.assert_array_equal(losses, lp.losses_of(V, F, uv, texture(), params))


def test_waiting_for_workers_yields_the_same_progress_again(monkeypatch):
    # A wait far shorter than any chunk: the generator must come back with unchanged progress while it waits.
    monkeypatch.setattr(worker_pool, "WAIT_SECONDS", 1e-4)
    V, F, uv = grid_mesh()
    progress = []
    result = run_generator(tw.iter_optimize_triangles(V, F, uv, texture(), evaluations=10, workers=2,
                                                      chunk_size=4), lambda *step: progress.append(step))
    assert progress[0] == (0, 8) and progress[-1] == (8, 8)
    assert any(a == b for a, b in zip(progress, progress[1:]))  # heartbeats: the same count twice in a row
    assert [done for done, _ in progress] == sorted(done for done, _ in progress)
    serial = tw.optimize_triangles(V, F, uv, texture(), evaluations=10, workers=1)
    np.testing.assert_array_equal(result.params, serial.params)


def test_fit_charts_drives_a_generator_measure_to_the_same_result():
    V, F, uv = grid_mesh()
    targets = np.tile([0.1, 0.8, 0.7, 0.0], (8, 1))
    weights = np.full(8, 1e-3)
    calls = []

    def measure(fits):
        return lp.losses_at(V, F, uv, texture(), np.stack(fits))

    def measure_stepwise(fits):
        calls.append(len(calls))
        return (yield from lp.iter_losses_at(V, F, uv, texture(), np.stack(fits), chunk_size=2))

    plain = fit_charts(F, uv, targets, weights, weights, measure=measure)
    steps = []
    stepwise = run_generator(iter_fit_charts(F, uv, targets, weights, weights, measure=measure_stepwise),
                             lambda *step: steps.append(step))
    assert calls == [0]  # once, for both fits
    np.testing.assert_array_equal(stepwise.uv, plain.uv)
    np.testing.assert_array_equal(stepwise.losses, plain.losses)
    total = steps[-1][1]
    assert steps[-1][0] == total and len(steps) > 2 * 5  # the measurements' steps came through


def _held_pool_start(monkeypatch):
    """Make :func:`worker_pool._make_pool` wait until the returned event is set: a stage that blocked on the
    start instead of handing control back would fail here (the wait runs out) rather than hang."""
    release = threading.Event()
    make_pool = worker_pool._make_pool

    def held(workers, state, shared):
        assert release.wait(60), "the stage did not hand control back while its worker pool started"
        return make_pool(workers, state, shared)

    monkeypatch.setattr(worker_pool, "_make_pool", held)
    return release


def test_the_stage_hands_control_back_while_its_worker_pool_starts(monkeypatch):
    V, F, uv = grid_mesh()
    release = _held_pool_start(monkeypatch)
    stage = tw.iter_optimize_triangles(V, F, uv, texture(), evaluations=10, workers=2, chunk_size=4)
    assert next(stage) == (0, 8)  # before the pool starts
    for _ in range(3):  # the pool is still starting: the same count again, every WAIT_SECONDS
        assert next(stage) == (0, 8)
    release.set()
    result = run_generator(stage)
    serial = tw.optimize_triangles(V, F, uv, texture(), evaluations=10, workers=1)
    np.testing.assert_array_equal(result.params, serial.params)
    np.testing.assert_array_equal(result.loss, serial.loss)


def test_closing_the_stage_while_its_worker_pool_starts_stops_the_workers(monkeypatch):
    V, F, uv = grid_mesh()
    release = _held_pool_start(monkeypatch)
    before = set(multiprocessing.active_children())
    stage = lp.iter_losses_at(V, F, uv, texture(), 0.5 + 0.6 * (uv - 0.5), workers=2, chunk_size=2)
    next(stage)
    next(stage)
    stage.close()  # returns at once; the workers are stopped once they are up
    release.set()
    deadline = time.monotonic() + 60
    while set(multiprocessing.active_children()) - before and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not set(multiprocessing.active_children()) - before


def test_fit_charts_gives_the_chart_finish_steps_of_its_own(monkeypatch):
    # The fold restore (two shared areas), the stacks and the chart turns run on the whole mesh: neither the
    # solver's last iteration nor the measurement's start may share their steps, nor may they share one.
    from perceptual_uv.core import chartfit

    V, F, uv = grid_mesh()
    targets = np.tile([0.1, 0.8, 0.7, 0.0], (8, 1))
    weights = np.full(8, 1e-3)
    events = []
    finish = chartfit._iter_finish_charts

    def recorded_finish(*args, **kwargs):
        events.append("finish")
        result = yield from finish(*args, **kwargs)
        events.append("finished")
        return result

    def measure(fits):
        events.append("measure")
        return lp.losses_at(V, F, uv, texture(), np.stack(fits))

    solve = chartfit.iter_solve_meshwise

    def recorded_solve(*args, **kwargs):
        result = yield from solve(*args, **kwargs)
        events.append("solved")
        return result

    monkeypatch.setattr(chartfit, "_iter_finish_charts", recorded_finish)
    monkeypatch.setattr(chartfit, "iter_solve_meshwise", recorded_solve)
    fit = run_generator(iter_fit_charts(F, uv, targets, weights, weights, measure=measure, max_iterations=3),
                        lambda *step: events.append(step))
    steps = 3 + 1
    finishes = (2 * 3, 2 * steps)  # both fits' iterations done
    solved = [n for n, event in enumerate(events) if event == "solved"]
    assert len(solved) == 2
    for index in range(2):
        at = [n for n, event in enumerate(events) if event == "finish"][index]
        end = [n for n, event in enumerate(events) if event == "finished"][index]
        assert at > solved[-1] + 1 and events[at - 1] == finishes  # after both fits, a yield before the finish
        # the fold restore yields after each of its two shared areas (no stacks here: the turns follow)
        assert events[at + 1:end] == [finishes] * 2
        assert events[end + 1] == finishes  # and one between it and what follows:
        assert events[end + 2] == ("measure" if index == 1 else finishes)  # the next finish, the measurement
    assert events.count("measure") == 1  # both fits in one measurement
    assert events[-1] == (2 * steps, 2 * steps)
    np.testing.assert_array_equal(fit.uv, fit_charts(F, uv, targets, weights, weights, measure=measure,
                                                     max_iterations=3).uv)


def test_a_slow_meshwise_iteration_hands_control_back(monkeypatch):
    # Each Newton solve made to take 0.4 s (tea_set_01's factorizations take about a quarter of a second): the
    # generator must come back every 0.1 s meanwhile and reach the same result.
    from perceptual_uv.core import meshwise_global

    V, F, uv = grid_mesh()
    targets = np.tile([0.1, 0.8, 0.7, 0.0], (8, 1))
    weights = np.full(8, 1e-3)
    plain = solve_meshwise(F, uv, targets, weights, weights, max_iterations=3)
    newton_step = meshwise_global._NewtonSolver.newton_step

    def slow(self, *args):
        time.sleep(0.4)
        return newton_step(self, *args)

    monkeypatch.setattr(meshwise_global._NewtonSolver, "newton_step", slow)
    stage = iter_solve_meshwise(F, uv, targets, weights, weights, max_iterations=3)
    steps, longest = [], 0.0
    while True:
        started = time.perf_counter()
        try:
            steps.append(next(stage))
        except StopIteration as finished:
            result = finished.value
            break
        longest = max(longest, time.perf_counter() - started)
    assert longest < 0.25
    assert steps.count((0, 3)) >= 1 + 3  # the set-up, then the same count again while the first solve sleeps
    assert list(dict.fromkeys(steps)) == [(i, 3) for i in range(result.iterations + 1)]
    np.testing.assert_array_equal(result.uv, plain.uv)


def test_the_meshwise_factorizations_are_made_and_dropped_in_one_thread(monkeypatch):
    # scipy's SuperLU keeps a factor's memory when another thread than its own frees it (scipy issue 15921):
    # every solve and the final release must run in the same thread, also when the generator is closed early.
    from perceptual_uv.core import meshwise_global

    V, F, uv = grid_mesh()
    targets = np.tile([0.1, 0.8, 0.7, 0.0], (8, 1))
    weights = np.full(8, 1e-3)
    calls = []
    newton_step, release = meshwise_global._NewtonSolver.newton_step, meshwise_global._NewtonSolver.release

    def recorded_step(self, *args):
        calls.append(("step", threading.get_ident()))
        return newton_step(self, *args)

    def recorded_release(self):
        calls.append(("release", threading.get_ident()))
        release(self)

    monkeypatch.setattr(meshwise_global._NewtonSolver, "newton_step", recorded_step)
    monkeypatch.setattr(meshwise_global._NewtonSolver, "release", recorded_release)
    for closed_early in (False, True):
        calls.clear()
        stage = iter_solve_meshwise(F, uv, targets, weights, weights, max_iterations=3)
        if closed_early:
            while ("step",) not in [call[:1] for call in calls]:
                next(stage)
            stage.close()
        else:
            run_generator(stage)
        deadline = time.monotonic() + 10
        while ("release",) not in [call[:1] for call in calls] and time.monotonic() < deadline:
            time.sleep(0.01)
        kinds = [kind for kind, _ in calls]
        assert kinds.count("step") >= 1 and kinds[-1] == "release" and kinds.count("release") == 1
        assert len({ident for _, ident in calls}) == 1
        assert calls[0][1] != threading.get_ident()


def test_the_two_meshwise_fits_iterate_at_the_same_time(monkeypatch):
    # Each Newton solve made to take 0.2 s: driven in turn, the fit without and the fit with rotation targets
    # solve in two threads whose solves overlap, and the result is the one of the fits run one after the other.
    from perceptual_uv.core import meshwise_global

    V, F, uv = grid_mesh()
    targets = np.tile([0.1, 0.8, 0.7, 0.0], (8, 1))
    weights = np.full(8, 1e-3)

    def measure(fits):
        return lp.losses_at(V, F, uv, texture(), np.stack(fits))

    one_after_the_other = [solve_meshwise(F, uv, targets, rotation_weights, weights, max_iterations=2).uv
                           for rotation_weights in (np.zeros(8), weights)]
    solves = []
    newton_step = meshwise_global._NewtonSolver.newton_step

    def slow(self, *args):
        started = time.perf_counter()
        time.sleep(0.2)
        solves.append((threading.get_ident(), started, time.perf_counter()))
        return newton_step(self, *args)

    monkeypatch.setattr(meshwise_global._NewtonSolver, "newton_step", slow)
    fit = run_generator(iter_fit_charts(F, uv, targets, weights, weights, measure=measure, max_iterations=2))
    assert len({ident for ident, _, _ in solves}) == 2
    assert any(a[0] != b[0] and a[1] < b[2] and b[1] < a[2] for a in solves for b in solves)
    for made, expected in zip(fit.fits, one_after_the_other):
        np.testing.assert_array_equal(made.uv, expected)


def test_chunks_of_neighbouring_faces_come_in_a_fixed_order_that_samples_the_whole_mesh():
    """The workers' chunks hold consecutive faces and come in a fixed pseudo-random order: the first chunks done
    are a sample of the whole mesh (its costly faces are often neighbours in the face order), the same in every
    run."""
    faces = np.arange(100, 260)
    chunks = worker_pool._chunks(faces, 16)
    assert sorted(chunk[0] for chunk in chunks) == list(range(100, 260, 16))
    assert all(np.array_equal(chunk, np.arange(chunk[0], chunk[0] + 16)) for chunk in chunks)
    assert [chunk[0] for chunk in chunks] == [chunk[0] for chunk in worker_pool._chunks(faces, 16)]
    assert {chunk[0] >= 180 for chunk in chunks[:2]} == {False, True}  # both halves of the mesh in the first two
    assert [len(chunk) for chunk in worker_pool._chunks(np.arange(10), 4)] in ([4, 4, 2], [4, 2, 4], [2, 4, 4])
