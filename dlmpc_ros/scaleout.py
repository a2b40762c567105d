"""Independent tasks run serially or on Dask (``dask.distributed``), with progress.

:func:`run_tasks` maps a module-level function over small picklable task records:
in this process, one after the other (``workers=1``, the reference); on an embedded
``LocalCluster`` of ``workers`` single-threaded processes; or on an existing cluster at
``scheduler``. Results come back in task order and are identical on every path (each
task pins numba and torch to one thread, so a worker computes as the serial path does).
A task that fails comes back as a :class:`TaskFailure` with its inputs; the others'
results are kept.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from tqdm import tqdm


@dataclass(frozen=True)
class TaskFailure:
    """A task that raised: which one, with what inputs, and why."""

    index: int
    """Its position in the task list."""
    inputs: str
    """``repr`` of its task record (shortened)."""
    error: str
    """The exception, one line, and the last lines of its traceback."""

    def __str__(self) -> str:
        return f'task {self.index} failed: {self.error} (inputs: {self.inputs})'


def default_workers() -> int:
    """The number of cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def pin_threads(torch: bool) -> None:
    """One compute thread for numba (and torch, imported here when ``torch``) in this
    process: a worker takes one core, and every path computes alike."""
    import numba
    numba.set_num_threads(1)
    if torch:  # opt-in: the data generation's tasks never load torch
        importlib.import_module('torch').set_num_threads(1)


def _guarded(fn: Callable[[Any], Any], task: Any, index: int, torch: bool) -> Any:
    pin_threads(torch)
    try:
        return fn(task)
    except Exception as err:  # a failed task is reported, the others go on
        tail = ''.join(traceback.format_exception(err)[-3:]).strip().replace('\n', ' | ')
        return TaskFailure(index, repr(task)[:300], f'{type(err).__name__}: {err} [{tail}]')


def run_tasks(fn: Callable[[Any], Any], tasks: Sequence[Any], workers: int = 1,
              scheduler: str | None = None, desc: str = 'tasks',
              show_progress: bool = True, torch: bool = False,
              on_result: Callable[[int, Any], None] | None = None) -> list[Any]:
    """``[fn(task) for task in tasks]``, in order, serially or on Dask (see the module).

    ``fn`` must be importable by the workers (a module-level function of an installed
    package); a task that raises gives a :class:`TaskFailure` in its place. ``torch``:
    the tasks use torch, whose threads are pinned too. ``on_result(index, result)`` is
    called here as each task finishes (e.g. to save it before the others are done).
    """
    if workers < 1:
        raise ValueError(f'workers must be >= 1, got {workers}')
    bar = tqdm(total=len(tasks), desc=desc, unit='task', disable=not show_progress)
    results: list[Any] = [None] * len(tasks)
    if scheduler is None and workers == 1:
        threads = _thread_counts()
        try:
            for i, task in enumerate(tasks):
                results[i] = _guarded(fn, task, i, torch)
                _report(bar, results[i], i, on_result)
        finally:
            _restore(threads)
            bar.close()
        return results
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
    try:
        with Client(scheduler or cluster) as client:
            futures = client.map(_guarded, [fn] * len(tasks), list(tasks),
                                 list(range(len(tasks))), [torch] * len(tasks), pure=False)
            index = {future.key: i for i, future in enumerate(futures)}
            for future in as_completed(futures):
                i = index[future.key]
                try:
                    results[i] = future.result()
                except Exception as err:  # the worker itself died
                    results[i] = TaskFailure(i, repr(tasks[i])[:300],
                                             f'{type(err).__name__}: {err}')
                _report(bar, results[i], i, on_result)
    finally:
        bar.close()
        if cluster is not None:
            cluster.close()
    return results


def _report(bar: tqdm, result: Any, index: int,
            on_result: Callable[[int, Any], None] | None) -> None:
    bar.update(1)
    if isinstance(result, TaskFailure):
        bar.write(str(result), file=sys.stderr)
    if on_result is not None:
        on_result(index, result)


def _thread_counts() -> tuple[int, int | None]:
    import numba
    torch = sys.modules.get('torch')
    return numba.get_num_threads(), (torch.get_num_threads() if torch is not None else None)


def _restore(threads: tuple[int, int | None]) -> None:
    import numba
    numba.set_num_threads(threads[0])
    if threads[1] is not None and 'torch' in sys.modules:
        sys.modules['torch'].set_num_threads(threads[1])
