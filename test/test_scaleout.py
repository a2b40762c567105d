"""Tasks on Dask give what the serial path gives, in order; a failure keeps the others."""

import numpy as np

from dlmpc_ros.evaluation.runs import RunSpec, RunTask, run_task
from dlmpc_ros.paths import models_dir
from dlmpc_ros.scaleout import TaskFailure, run_tasks


def test_two_local_workers_give_the_serial_results_and_report_a_failed_task():
    tasks = [RunTask(RunSpec('steps', 2, 'esc', round_trips=300), str(models_dir())),
             RunTask(RunSpec('sinusoidal', 3, 'fixed_best', round_trips=300,
                             plant={'pump': 1.6}), str(models_dir())),
             RunTask(RunSpec('chirp', 4, 'esc', round_trips=300), '/nonexistent/models')]
    serial = run_tasks(run_task, tasks, workers=1, show_progress=False)
    parallel = run_tasks(run_task, tasks, workers=2, show_progress=False)
    for a, b in zip(serial[:2], parallel[:2]):
        for name in ('round_trip', 'K', 'E', 'M', 'O', 'angles', 'mode'):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        assert a.meta == b.meta
    assert serial[1].meta['plant']['pump'] == 1.6
    for failed in (serial[2], parallel[2]):  # esc needs no models: the run itself works
        assert not isinstance(failed, TaskFailure)
    broken = [RunTask(RunSpec('chirp', 4, 'fixed_best', round_trips=300),
                      '/nonexistent/models')]
    result, = run_tasks(run_task, broken, workers=1, show_progress=False)
    assert isinstance(result, TaskFailure) and 'oracle.npz' in result.error
    assert 'fixed_best' in result.inputs and result.index == 0
