"""The executor for independent jobs (jaxsim.executor): local worker processes pinned to their
cores, a local Ray instance, a worker killed mid-job, a job that raises, and the [executor]
settings."""

import importlib.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from jaxsim.executor import (ExecutorError, ExecutorSettings, InProcess, LocalProcesses,
                             RayExecutor, executor_from, worker_cores)

# Jobs: module-level functions, so that worker processes can be sent them.


def where_am_i(index):
    """The job's index, the cores it may run on and the thread count its environment sets."""
    return index, sorted(os.sched_getaffinity(0)), os.environ.get("PJRT_NPROC"), os.getpid()


def dies_once(folder, index, how="SIGKILL"):
    """index × 10, after noting the run in folder/runs; job 1, the first time it runs
    (folder/killed marks that it did), kills its own process (SIGKILL) or stops as a training
    does after a SIGTERM it noted (KeyboardInterrupt, "SIGTERM")."""
    with open(folder / "runs", "a") as runs:
        runs.write(f"{index}\n")
    marker = folder / "killed"
    if index == 1 and not marker.exists():
        marker.touch()
        if how == "SIGTERM":
            raise KeyboardInterrupt
        os.kill(os.getpid(), signal.SIGKILL)
    return index * 10


def always_dies(index):
    os.kill(os.getpid(), signal.SIGKILL)


def rejects_two(index):
    if index == 2:
        raise ValueError(f"job input {index} is bad")
    return index


def check_four_jobs_and_a_kill(executor, folder, how="SIGKILL"):
    """4 jobs, one of whose worker is killed (`dies_once`) the first time it runs: every result
    comes back, and only the killed job ran twice."""
    folder.mkdir(exist_ok=True)
    results = dict(executor.map_unordered(dies_once, [(folder, i, how) for i in range(4)]))
    assert results == {0: 0, 1: 10, 2: 20, 3: 30}
    runs = sorted(int(line) for line in (folder / "runs").read_text().split())
    assert runs == [0, 1, 1, 2, 3]


def check_a_raising_job(executor):
    """A job's ValueError reaches the caller as itself, with a note naming the job; the other
    jobs' results came back before it."""
    seen = []
    with pytest.raises(ValueError, match="job input 2 is bad") as error:
        for index, result in executor.map_unordered(rejects_two, [(i,) for i in range(4)]):
            seen.append(index)
    assert "raised by job 2 (rejects_two(2,))" in "\n".join(error.value.__notes__)
    assert 2 not in seen


def test_four_jobs_on_two_local_workers_each_pinned_to_its_cores():
    with LocalProcesses(2) as executor:
        results = dict(executor.map_unordered(where_am_i, [(i,) for i in range(4)]))
        assert sorted(results) == [0, 1, 2, 3]
        assert all(results[i][0] == i for i in range(4))
        by_worker = {pid: (tuple(cores), threads) for _, cores, threads, pid in results.values()}
        assert len(by_worker) == 2                  # both workers ran jobs, and no more started
        assert sorted(by_worker.values()) == sorted(
            (cores, str(len(cores))) for cores in executor.cores)
        # The workers are kept: a second batch of jobs runs in the same processes.
        again = dict(executor.map_unordered(where_am_i, [(i,) for i in range(2)]))
        assert {pid for *_, pid in again.values()} <= set(by_worker)
    assert executor.cores == worker_cores(2)
    cores = sorted(os.sched_getaffinity(0))
    assert executor.cores[0] == tuple(cores[:max(1, len(cores) // 2)])


@pytest.mark.parametrize("how", ["SIGKILL", "SIGTERM"])
def test_a_killed_local_worker_loses_no_result_and_its_job_runs_again(tmp_path, how):
    with LocalProcesses(2) as executor:
        check_four_jobs_and_a_kill(executor, tmp_path, how)


def waits_for_sigterm(folder):
    """Notes a SIGTERM in folder/terminated and ends; until then waits (a minute at most)."""
    def note(signum, frame):
        (folder / "terminated").touch()
        os._exit(0)
    signal.signal(signal.SIGTERM, note)
    (folder / "ready").touch()
    signal.sigtimedwait([], 60)


def test_a_local_worker_gets_a_sigterm_when_its_parent_is_killed(tmp_path):
    """So a training job checkpoints and ends (`_job`) rather than run on, unseen."""
    parent = subprocess.Popen([sys.executable, "-c", (
        "import sys; from pathlib import Path; sys.path.insert(0, 'tests')\n"
        "from jaxsim.executor import LocalProcesses\n"
        "from test_executor import waits_for_sigterm\n"
        "with LocalProcesses(1) as executor:\n"
        f"    list(executor.map_unordered(waits_for_sigterm, [(Path({str(tmp_path)!r}),)]))\n")],
        cwd=Path(__file__).resolve().parents[1])
    try:
        wait_for(tmp_path / "ready", parent)
        parent.kill()
        parent.wait()
        wait_for(tmp_path / "terminated")
    finally:
        parent.kill()


def wait_for(path, process=None, seconds=60):
    deadline = time.monotonic() + seconds
    while not path.exists():
        assert process is None or process.poll() is None, "the parent ended by itself"
        assert time.monotonic() < deadline, f"no {path.name} after {seconds} s"
        time.sleep(0.05)


def test_a_raising_job_is_raised_as_itself_naming_the_job():
    with LocalProcesses(2) as executor:
        check_a_raising_job(executor)
    check_a_raising_job(InProcess())


def test_a_job_whose_worker_keeps_dying_and_a_job_that_cannot_be_sent_are_errors():
    with LocalProcesses(1, max_retries=1) as executor:
        with pytest.raises(ExecutorError, match=r"job 0 \(always_dies\(0,\)\) lost its worker 2 "
                                                "times, more than max_retries = 1 allows; the "
                                                "last time it was killed by SIGKILL"):
            list(executor.map_unordered(always_dies, [(0,)]))
        with pytest.raises(ExecutorError, match="job 0 .* cannot be sent to a worker process: "
                                                ".*not a lambda or a closure"):
            list(executor.map_unordered(lambda x: x, [(0,)]))


def test_one_local_worker_runs_in_this_process_and_settings_are_checked(monkeypatch):
    assert isinstance(executor_from(ExecutorSettings()), InProcess)
    results = dict(executor_from(ExecutorSettings()).map_unordered(where_am_i, [(0,), (1,)]))
    assert {pid for *_, pid in results.values()} == {os.getpid()}
    assert isinstance(executor_from(ExecutorSettings(workers=2)), LocalProcesses)
    for bad, message in [
        (dict(backend="dask"), "backend must be one of local, ray; got 'dask'"),
        (dict(workers=0), "workers must be at least 1; got 0"),
        (dict(max_retries=-1), "max_retries must be at least 0; got -1"),
        (dict(address="auto"), "address .* names a Ray cluster; it needs backend = \"ray\""),
        (dict(workers=2, cores_per_worker=len(os.sched_getaffinity(0)) + 1),
         "cores_per_worker must be between 1 and the"),
    ]:
        with pytest.raises(ValueError, match=message):
            ExecutorSettings(**bad)
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
    with pytest.raises(ValueError, match=r"pip install 'takeoff\[ray\]'"):
        ExecutorSettings(backend="ray")
    with pytest.raises(ExecutorError, match=r"pip install 'takeoff\[ray\]'"):
        RayExecutor(2)


@pytest.fixture(scope="module")
def ray_instance():
    """A local Ray instance with 2 CPUs and no dashboard, shut down after this file's tests.
    Ray's workers cannot import this test module, so its jobs travel by value."""
    ray = pytest.importorskip("ray", reason="the ray extra (pip install 'takeoff[ray]') is not "
                                            "installed")
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()
    ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def test_four_jobs_and_a_killed_worker_on_a_local_ray_instance(ray_instance, tmp_path):
    with RayExecutor(2) as executor:
        results = dict(executor.map_unordered(where_am_i, [(i,) for i in range(4)]))
        assert sorted(results) == [0, 1, 2, 3]
        assert {threads for _, _, threads, _ in results.values()} == {"1"}
        check_four_jobs_and_a_kill(executor, tmp_path / "killed")
        check_four_jobs_and_a_kill(executor, tmp_path / "stopped", "SIGTERM")
        check_a_raising_job(executor)
    assert ray_instance.is_initialized()        # the executor did not start it, nor stops it


def test_the_executor_module_imports_neither_ray_nor_jax():
    code = "import sys, jaxsim.executor; print('ray' in sys.modules, 'jax' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout.split() == ["False", "False"]
