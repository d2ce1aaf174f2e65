"""Progress of a run: driving a stage written as a generator, and the whole run's fraction and time left."""
import threading
import time

__all__ = ["run_generator", "report_while_waiting", "relay_stage", "InThread", "wait_for_threads", "RunProgress",
           "StageParts", "format_seconds", "stage_line"]


def run_generator(generator, progress=None):
    """Drive ``generator`` to completion and return its ``StopIteration`` value.

    Parameters
    ----------
    generator : generator
        A stage such as ``iter_optimize_triangles`` or ``iter_solve_meshwise``.
    progress : callable, optional
        Called with each yielded item unpacked, e.g. ``progress(done, total)``.
    """
    while True:
        try:
            item = next(generator)
        except StopIteration as finished:
            return finished.value
        if progress is not None:
            progress(*item)


def report_while_waiting(waiting, progress):
    """Generator: drive ``waiting`` (a generator that yields None while it waits, e.g. :meth:`InThread.wait`),
    yielding ``progress`` in place of each None; returns ``waiting``'s value.

    A stage that yields progress values (``(done, total)``, a pipeline step) keeps yielding the same one while a
    thread works for it."""
    while True:
        try:
            next(waiting)
        except StopIteration as finished:
            return finished.value
        yield progress


# The InThreads whose function has not returned yet (:func:`wait_for_threads`).
_RUNNING = set()
_RUNNING_LOCK = threading.Lock()


def wait_for_threads(timeout=None):
    """Block until the function of every :class:`InThread` started so far has returned, or ``timeout`` seconds
    have passed (None: no limit); whether all of them have.

    A process calls it before it exits, after closing its stages' generators (see :class:`InThread`'s notes).
    """
    deadline = None if timeout is None else time.monotonic() + float(timeout)
    while True:
        with _RUNNING_LOCK:
            running = next(iter(_RUNNING), None)
        if running is None:
            return True
        left = None if deadline is None else deadline - time.monotonic()
        if left is not None and left <= 0:
            return False
        running._returned.wait(left)


class InThread:
    """``function(*args)`` running in a daemon thread, so that a generator can hand control back while it runs.

    Starting a worker pool, waiting for its processes to exit, or a session's first import of the stages'
    modules take about a second each; in a thread they leave a stage's generator free to yield every
    ``interval`` seconds (a modal operator's tick) meanwhile.

    Parameters
    ----------
    function : callable
    *args
        Its arguments.
    interval : float, optional
        Seconds :meth:`wait` waits between two yields.

    Notes
    -----
    A generator closed while its function runs (Esc in Blender, a cancelled command line run) does not wait for
    it: the function runs on and its result is dropped, and the functions given here are bounded (a second or
    two) or stop at the next check of a flag their generator sets when closed. Blender's interface stays free
    meanwhile; a process that is about to exit calls :func:`wait_for_threads` first, because a daemon thread
    still running numpy or scipy while the interpreter shuts down breaks the shutdown (Python 3.11 then fails to
    flush standard output and the process exits 120 instead of its own code).
    """

    def __init__(self, function, *args, interval=0.1):
        self._value = self._error = None
        self._interval = float(interval)
        self._returned = threading.Event()
        with _RUNNING_LOCK:
            _RUNNING.add(self)
        self._thread = threading.Thread(target=self._run, args=(function, args), daemon=True,
                                        name="perceptual_uv-worker")
        try:
            self._thread.start()
        except BaseException:
            with _RUNNING_LOCK:
                _RUNNING.discard(self)
            raise

    def _run(self, function, args):
        try:
            self._value = function(*args)
        except BaseException as error:  # noqa: BLE001  raised again in the generator that waits for it
            self._error = error
        finally:
            with _RUNNING_LOCK:
                _RUNNING.discard(self)
            self._returned.set()

    def wait(self):
        """Generator: yield None every ``interval`` seconds until the function has returned; return its value,
        or raise its exception.

        It waits on an event the thread sets, not on ``Thread.join``: a signal handler's exception (Ctrl-C, or
        the command line's SIGTERM) raised inside ``Thread.join(timeout)`` makes Python 3.11 release the lock
        that the running thread holds and mark the thread stopped while it runs on, after which joining it
        returns at once; the event still tells when the function returns (:func:`wait_for_threads`)."""
        while not self._returned.wait(self._interval):
            yield None
        if self._error is not None:
            raise self._error
        return self._value

    def join(self):
        """Block until the function has returned; its value, or None if it raised."""
        self._returned.wait()
        return self._value


class RunProgress:
    """The fraction of a whole run done and the time left, from its stages' expected shares of the time.

    A run is a sequence of stages; stage ``k`` is expected to take ``shares[k]`` of the whole run. The fraction
    done when ``done`` of ``total`` units of a stage are finished is the sum of the earlier stages' shares plus
    that stage's share times ``done / total``; the time left is the time so far scaled by the fraction left over
    the fraction done. Stages missing from ``shares`` (and a share of 0) count as instantaneous. Work an earlier
    run did (:meth:`skip`: results reused or resumed) moves the bar but not the time left, which is the time so
    far scaled by the fraction left over the fraction this run did.

    Parameters
    ----------
    shares : dict of str to float
        Stage name -> expected share of the run's time, in the order the stages run (normalized to sum 1).
    clock : callable, optional
        Seconds as a float; ``time.perf_counter`` by default (tests pass their own).
    started : float, optional
        The clock's reading when the run started; by default, the construction's.
    """

    def __init__(self, shares, *, clock=time.perf_counter, started=None):
        total = sum(shares.values())
        if not shares or total <= 0 or any(share < 0 for share in shares.values()):
            raise ValueError(f"stage shares must be non-negative with a positive sum, got {shares}")
        self._start = {}
        before = 0.0
        for stage, share in shares.items():
            self._start[stage] = (before / total, share / total)
            before += share
        self._clock = clock
        self._started = clock() if started is None else started
        self._fraction = 0.0
        self._skipped = 0.0

    def _share_of(self, stage, done, total):
        share = self._start[stage][1] if stage in self._start else 0.0
        return share * min(max(done / total if total else 1.0, 0.0), 1.0)

    def update(self, stage, done, total):
        """Record ``done`` of ``total`` units of ``stage``; return ``(fraction, seconds_left)``.

        The fraction never goes back (a stage that restarts its count does not move the bar back). Seconds left
        are None until this run has done a hundredth of the whole, when the estimate would be noise.
        """
        if stage in self._start:
            self._fraction = max(self._fraction, self._start[stage][0] + self._share_of(stage, done, total))
        elapsed = self._clock() - self._started
        own = self._fraction - self._skipped
        if own < 0.01:
            return self._fraction, None
        return self._fraction, elapsed * (1.0 - self._fraction) / own

    def skip(self, stage, done, total):
        """Record that ``done`` of ``total`` units of ``stage`` were done before this run (reused results, a
        stage resumed from a checkpoint); call it before the stage's first :meth:`update`."""
        self._skipped += self._share_of(stage, done, total)


class StageParts:
    """A stage made of parts of known shares of its time: each part's count reported as the whole stage's.

    A stage whose parts each count their own units (faces measured, iterations, faces measured again) and report
    them as the stage's ``(done, total)`` reaches ``total`` with the first part that finishes counting, so the
    run's bar stands at the stage's end for all the parts after it. Here the parts' expected shares of the
    stage's time (a :class:`RunProgress` of the parts) turn each part's count into the stage's fraction, reported
    in ``units``; the line names the part's own count and the time left in the whole stage at its rate so far.

    Parameters
    ----------
    name : str
        The pipeline stage the parts belong to (passed on to ``step``).
    shares : dict of str to float
        Part name -> expected share of the stage's time, in the order the parts run.
    step : callable
        ``step(name, done, total, line)`` of the pipeline.
    units : int, optional
        The stage's ``total`` (its fraction is reported in ``1 / units`` steps).
    clock : callable, optional
        As :class:`RunProgress`'s.
    started : float, optional
        The clock's reading when the stage started; by default, the construction's.
    """

    def __init__(self, name, shares, step, *, units=1000, clock=time.perf_counter, started=None):
        self._parts = RunProgress(shares, clock=clock, started=started)
        self._name = name
        self._step = step
        self._units = int(units)

    def step(self, part, done, total, label):
        """``step(name, stage units done, units, "label: done/total, ... left in this stage")`` for ``done`` of
        ``total`` units of ``part``."""
        fraction, left = self._parts.update(part, done, total)
        return self._step(self._name, round(fraction * self._units), self._units, stage_line(label, done, total, left))

    def relay(self, stage, part, label):
        """Generator: re-yield ``stage``'s ``(done, total)`` as :meth:`step` of ``part``; returns its value."""
        while True:
            try:
                done, total = next(stage)
            except StopIteration as finished:
                return finished.value
            yield self.step(part, done, total, label)


def format_seconds(seconds):
    """``seconds`` as a short duration for a progress line: "45 s", "3 min 05 s", "1 h 02 min"."""
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


def stage_line(label, done, total, left=None):
    """A stage's progress line: ``"label: done/total"``, and ``", 1 min 05 s left in this stage"`` when ``left``
    (seconds) is known."""
    return f"{label}: {done}/{total}" + (f", {format_seconds(left)} left in this stage" if left is not None else "")


def relay_stage(stage, name, label, started, step, *, message=None):
    """Generator: re-yield a stage's ``(done, total)`` progress as ``step(name, done, total, line)``; returns the
    stage's value.

    ``line`` is ``"label: done/total"`` with the time left in this stage (from ``started``, a
    ``time.perf_counter()`` reading, and the count this call first saw: a resumed stage starts past 0), or
    ``message(done, total)`` when ``message`` is given.
    """
    first = None  # the count a stage starts from (a resumed stage starts past 0)
    while True:
        try:
            done, total = next(stage)
        except StopIteration as finished:
            return finished.value
        if message is not None:
            yield step(name, done, total, message(done, total))
            continue
        first = done if first is None else first
        elapsed = time.perf_counter() - started
        left = elapsed / (done - first) * (total - done) if done > first else None
        yield step(name, done, total, stage_line(label, done, total, left))


