"""Running a stage written as a generator (yields ``(done, total)``, returns its result) to the end."""

__all__ = ["run_generator"]


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
