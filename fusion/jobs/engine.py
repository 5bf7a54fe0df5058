"""Where a job's coarse tasks run: this process, worker processes of this machine, or a Dask
cluster.

:func:`run_tasks` calls ``fn(item)`` for every item and yields each outcome as it finishes,
whatever runs it: in this process (``jobs=1``), in a :class:`~concurrent.futures.
ProcessPoolExecutor` (``jobs=N``), or on the workers of a ``dask.distributed`` client
(:mod:`fusion.jobs.cluster` opens one). ``fn`` must be a module-level function and ``item``
picklable; a task that raises (or whose worker process dies) is reported, the others go on.
On a Dask cluster a task whose worker is lost runs again on another worker (the scheduler
does that); it is yielded once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

__all__ = ["TaskOutcome", "run_tasks"]

#: ``(index of the item, ok, result)``; when not ok, ``result`` is an error message.
TaskOutcome = tuple[int, bool, Any]


def run_tasks(fn: Callable[[Any], Any], items: Sequence[Any], *, jobs: int = 1,
              client: Any = None) -> Iterator[TaskOutcome]:
    """Run ``fn(item)`` for every item; yield ``(index, ok, result or message)`` as each ends.

    Args:
        fn: a module-level function (worker processes import it by name).
        items: picklable arguments, one task each.
        jobs: worker processes on this machine (1: in this process); ignored with ``client``.
        client: a ``dask.distributed.Client``: the tasks run on its workers.

    Raises:
        ValueError: ``jobs`` < 1.
    """
    if client is not None:
        yield from _run_dask(fn, items, client)
    elif jobs == 1:
        for i, item in enumerate(items):
            try:
                yield i, True, fn(item)
            except Exception as exc:  # reported; the other tasks go on
                yield i, False, _message(exc)
    elif jobs > 1:
        yield from _run_pool(fn, items, jobs)
    else:
        raise ValueError(f"jobs must be >= 1, got {jobs}")


def _message(exc: BaseException) -> str:
    return f"{exc or type(exc).__name__} ({type(exc).__name__})"


def _run_pool(fn, items, jobs: int) -> Iterator[TaskOutcome]:
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(max_workers=min(jobs, max(len(items), 1))) as pool:
        futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
        try:
            for fut in as_completed(futures):
                try:
                    yield futures[fut], True, fut.result()
                except Exception as exc:  # the task raised, or its worker process died
                    yield futures[fut], False, _message(exc)
        except (KeyboardInterrupt, GeneratorExit):  # Ctrl-C or the caller stopped early:
            pool.shutdown(wait=False, cancel_futures=True)  # start no other task
            raise


def _run_dask(fn, items, client) -> Iterator[TaskOutcome]:
    from distributed import as_completed

    # pure=False: every submission is a task of its own (two equal items are two tasks)
    futures = {client.submit(fn, item, pure=False): i for i, item in enumerate(items)}
    try:
        for fut in as_completed(list(futures)):
            i = futures.pop(fut)
            try:
                result = fut.result()
            except Exception as exc:  # raised in the task, or KilledWorker after retries
                yield i, False, _message(exc)
            else:
                yield i, True, result
            fut.release()  # the result lives on the worker until released
    finally:
        for fut in futures:  # left over when the caller stops early (Ctrl-C)
            fut.cancel()
