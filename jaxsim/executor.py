"""One way to run independent jobs: work that cannot share one compiled program, such as the
picks of a batched BDS round (`bds.search`) or the members of a sweep that run as separate runs.

`Executor.map_unordered(fn, jobs)` runs fn(*args) for each args of `jobs`, at most `workers` at
once, and yields (job index, result) as each job finishes. The backends:

- `InProcess`: one job after another in this process (what one worker means locally: no worker
  process, no pickling, the same speed as calling fn).
- `LocalProcesses(workers, cores_per_worker)`: worker processes on this machine, started with
  the `spawn` context (JAX is not fork-safe) and kept for the executor's life, so a worker pays
  for its imports and compilations once. Each worker is pinned to its own cores
  (`os.sched_setaffinity`; by default this process's cores shared out evenly) and its thread
  pools are sized to match (`thread_environment`). Jobs and results travel by pickle: fn must
  be a module-level function or a picklable object, not a lambda or closure.
- `RayExecutor(workers, address)`: tasks on a Ray cluster (the optional extra,
  `pip install 'takeoff[ray]'`; this module imports Ray only when that backend is made).
  `address` None or "local" starts a Ray instance on this machine; "auto" joins the cluster
  running here; "ray://host:10001" one elsewhere. A task takes `cores_per_worker` of the
  cluster's CPUs and gets the same thread-pool environment; Ray places tasks by CPU count, so
  they are not pinned to cores.

One rule for failures, on every backend:

- A job whose worker process dies (killed by a signal, out of memory) is run again on a fresh
  worker, at most `max_retries` times (a SIGTERM counts as such a death even when the job
  noted it and stopped cleanly, as a training does after checkpointing: `_job`); after that
  an `ExecutorError` names the job and how its worker died. No finished result is lost: each
  is yielded as it comes in.
- A job that raises is not run again: its exception is raised to the caller as itself (type and
  message kept, so callers catch it as they would from fn), with a note naming the job and,
  from a worker, the worker's traceback. Once a job has failed no further job starts; the jobs
  already running finish and their results are yielded before the error is raised.
- When the caller stops early (an error or Ctrl-C while it handles a result), the jobs still
  running are stopped: local workers are killed (and replaced on the next call), Ray tasks
  cancelled.

`ExecutorSettings` is a config's `[executor]` table and `executor_from(settings)` the executor it
names. An executor is a context manager; `close()` stops its workers (and a Ray instance it
started).
"""

import collections
import ctypes
import importlib.util
import multiprocessing
import multiprocessing.connection
import os
import pickle
import reprlib
import signal
import traceback
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator

BACKENDS = ("local", "ray")
PR_SET_PDEATHSIG = 1       # prctl's option: the signal a process gets when its parent ends
RAY_MISSING = ("the ray backend needs Ray, which is not installed here: "
               "pip install 'takeoff[ray]'")


class ExecutorError(RuntimeError):
    """A job the executor could not run: it could not be sent to a worker, or its worker died
    more often than `max_retries` allows. The message names the job."""


def thread_environment(threads) -> dict:
    """The environment variables that size a worker's thread pools to `threads` cores, set
    before JAX or NumPy start in it.

    PJRT_NPROC is the size of the XLA CPU client's two pools (the one that runs a program's
    parallel parts and Eigen's, for matrix products); without it XLA sizes them to the cores the
    process may run on, which pinning already limits, but a Ray task is not pinned. (The often
    quoted `XLA_FLAGS=... intra_op_parallelism_threads=N` is not an XLA flag: JAX 0.10's XLA
    ignores it.) OMP_NUM_THREADS and OPENBLAS_NUM_THREADS size OpenMP's and NumPy's BLAS
    pools."""
    return {name: str(threads)
            for name in ("PJRT_NPROC", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}


def _check_counts(workers, max_retries):
    if workers < 1:
        raise ValueError(f"workers must be at least 1; got {workers}")
    if max_retries < 0:
        raise ValueError(f"max_retries must be at least 0; got {max_retries}")


def worker_cores(workers, cores_per_worker=None) -> list[tuple[int, ...]]:
    """The cores each of `workers` local workers is pinned to: `cores_per_worker` of the cores
    this process may run on (None: an equal share of them, at least one) for each worker in
    turn, starting again from the first core when there are more workers than cores. A
    ValueError when a worker would need more cores than there are."""
    cores = sorted(os.sched_getaffinity(0))
    if cores_per_worker is not None and not 1 <= cores_per_worker <= len(cores):
        raise ValueError(f"cores_per_worker must be between 1 and the {len(cores)} cores this "
                         f"process may run on; got {cores_per_worker}")
    per = cores_per_worker or max(1, len(cores) // workers)
    return [tuple(cores[(k * per + i) % len(cores)] for i in range(per)) for k in range(workers)]


def _times(count):
    return "once" if count == 1 else f"{count} times"


def _describe(fn, args):
    """A job as a short text: fn's name and its arguments (long ones cut)."""
    name = getattr(fn, "__qualname__", type(fn).__qualname__)
    return f"{name}{reprlib.repr(tuple(args))}"


class Executor:
    """Runs independent jobs, at most `workers` at once, each run again at most `max_retries`
    times when its worker dies; see the module docstring for the rules. A backend provides
    `_start` (begin a job), `_finished` (wait for at least one job to end) and `_abandon` (stop
    the jobs still running)."""

    def __init__(self, workers, max_retries):
        _check_counts(workers, max_retries)
        self.workers, self.max_retries = workers, max_retries

    def map_unordered(self, fn: Callable, jobs: Iterable) -> Iterator[tuple[int, Any]]:
        """Run fn(*args) for each args of `jobs` and yield (index of args in jobs, result) as
        each job finishes."""
        jobs = [tuple(args) for args in jobs]
        waiting, running = collections.deque(range(len(jobs))), set()
        deaths, failure = collections.Counter(), None
        try:
            while running or (waiting and failure is None):
                while waiting and failure is None and len(running) < self.workers:
                    index = waiting.popleft()
                    self._start(index, fn, jobs[index])
                    running.add(index)
                for index, outcome, value in self._finished():
                    running.remove(index)
                    if outcome == "result":
                        yield index, value
                    elif outcome == "error":
                        failure = value if failure is None else failure
                    elif deaths[index] < self.max_retries:           # its worker died
                        deaths[index] += 1
                        waiting.appendleft(index)
                    elif failure is None:
                        failure = ExecutorError(
                            f"job {index} ({_describe(fn, jobs[index])}) lost its worker "
                            f"{_times(deaths[index] + 1)}, more than max_retries = "
                            f"{self.max_retries} allows; the last time {value}")
            if failure is not None:
                raise failure
        finally:
            self._abandon()

    def close(self):
        """Stop the workers."""

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()

    def _start(self, index, fn, args):
        raise NotImplementedError

    def _finished(self) -> list[tuple[int, str, Any]]:
        """Wait until at least one job has ended; for each, (index, "result", its result),
        (index, "error", the exception it raised, noted) or (index, "lost", how its worker
        died)."""
        raise NotImplementedError

    def _abandon(self):
        raise NotImplementedError


class InProcess(Executor):
    """Runs each job in this process when the caller asks for the next result."""

    def __init__(self):
        super().__init__(workers=1, max_retries=0)
        self._job = None

    def _start(self, index, fn, args):
        self._job = index, fn, args

    def _finished(self):
        (index, fn, args), self._job = self._job, None
        try:
            return [(index, "result", fn(*args))]
        except BaseException as error:              # Ctrl-C too: it is the job's to report
            error.add_note(f"raised by job {index} ({_describe(fn, args)})")
            return [(index, "error", error)]

    def _abandon(self):
        self._job = None


# ---------------------------------------------------------------------------------------------
# local worker processes


def end_with_parent(signum):
    """Ask the kernel to send this process `signum` when its parent ends (PR_SET_PDEATHSIG; on
    Linux only, elsewhere nothing)."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signum)
    except (OSError, AttributeError):
        pass


def _job(fn, args):
    """fn(*args) in a worker process. A KeyboardInterrupt there is a SIGTERM the job noted and
    stopped at (a training checkpoints first: `agents.rl.trainer.run`), so the worker then ends
    by that signal, and the rule for a worker killed by a signal applies: the job runs again,
    from that checkpoint."""
    try:
        return fn(*args)
    except KeyboardInterrupt:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)
        raise                                   # (a SIGTERM blocked in this thread)


def _serve(connection, cores, environment):
    """A worker process: pin itself and size its thread pools, then run the jobs that arrive
    on `connection` (pickled (fn, args)) one at a time, sending back ("result", value) or
    ("error", exception, traceback text, pid), until the connection closes. Ctrl-C is the
    parent's to handle: the worker ignores it and is stopped by the parent. A SIGTERM ends the
    worker (`_job`), and one comes when the parent ends without stopping it (killed), so a
    training job checkpoints and ends rather than run on unseen."""
    os.environ.update(environment)
    os.sched_setaffinity(0, cores)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    end_with_parent(signal.SIGTERM)
    while True:
        try:
            payload = connection.recv_bytes()
        except EOFError:
            return
        try:
            fn, args = pickle.loads(payload)
            reply = pickle.dumps(("result", _job(fn, args)))
        except BaseException as error:
            reply = pickle.dumps(("error", _sendable(error), traceback.format_exc(), os.getpid()))
        connection.send_bytes(reply)


def _sendable(error):
    """`error`, or a RuntimeError saying what it was when it cannot travel by pickle."""
    try:
        pickle.loads(pickle.dumps(error))
        return error
    except Exception:
        return RuntimeError(f"{type(error).__qualname__}: {error} (an exception that cannot be "
                            "pickled, so its type is not kept)")


def _death(exitcode):
    """How a worker process ended, from its exit code."""
    if exitcode is not None and exitcode < 0:
        name = signal.Signals(-exitcode).name
        hint = ", which the kernel's out-of-memory killer sends too" if name == "SIGKILL" else ""
        return f"it was killed by {name}{hint}"
    return f"it exited with code {exitcode}"


@dataclass
class _Worker:
    """A local worker process, the parent's end of its pipe, and the job it runs."""
    process: Any
    connection: Any
    job: Any = None             # (index, fn, args) of the job it runs, or None


class LocalProcesses(Executor):
    """Worker processes on this machine, pinned to cores; see the module docstring.

    `cores_per_worker` None shares this process's cores out evenly (at least one each); workers
    beyond the cores share them. Workers start when a job first needs them and are kept until
    `close()`; one that died is replaced when a job next needs it. They are daemonic (they end
    with this process), so a job cannot start worker processes of its own."""

    def __init__(self, workers, cores_per_worker=None, max_retries=2):
        super().__init__(workers, max_retries)
        self.cores = worker_cores(workers, cores_per_worker)
        self._context = multiprocessing.get_context("spawn")
        self._slots: list[_Worker | None] = [None] * workers

    def _start(self, index, fn, args):
        try:
            payload = pickle.dumps((fn, args))
        except Exception as error:
            raise ExecutorError(f"job {index} ({_describe(fn, args)}) cannot be sent to a worker "
                                f"process: {error}. A job for process workers must be picklable: "
                                "a function or object defined at module level, not a lambda or "
                                "a closure") from error
        slot = next(k for k, worker in enumerate(self._slots)
                    if worker is None or worker.job is None)
        if self._slots[slot] is not None and not self._slots[slot].process.is_alive():
            self._stop(slot)                # it died after its last job
        worker = self._slots[slot] = self._slots[slot] or self._spawn(slot)
        worker.job = index, fn, args
        try:
            worker.connection.send_bytes(payload)
        except OSError:
            pass            # it died just now: _finished reports the job lost

    def _spawn(self, slot):
        parent_end, child_end = self._context.Pipe()
        process = self._context.Process(
            target=_serve, name=f"takeoff-worker-{slot}", daemon=True,
            args=(child_end, self.cores[slot], thread_environment(len(self.cores[slot]))))
        process.start()
        child_end.close()
        return _Worker(process, parent_end)

    def _finished(self):
        busy = {}
        for slot, worker in enumerate(self._slots):
            if worker is not None and worker.job is not None:
                busy[worker.connection] = busy[worker.process.sentinel] = slot
        ready = multiprocessing.connection.wait(list(busy))
        outcomes = []
        for slot in sorted({busy[handle] for handle in ready}):
            worker = self._slots[slot]
            (index, fn, args), worker.job = worker.job, None
            try:
                data = worker.connection.recv_bytes() if worker.connection.poll() else None
            except (EOFError, OSError):
                data = None
            if data is None:
                self._stop(slot)
                outcomes.append((index, "lost", _death(worker.process.exitcode)))
                continue
            try:
                kind, value, *where = pickle.loads(data)
            except Exception as error:
                kind, value, where = "error", ExecutorError(
                    f"job {index} ({_describe(fn, args)}): its result cannot be read back from "
                    f"the worker process: {error}"), []
            if where:
                value.add_note(f"raised by job {index} ({_describe(fn, args)}) in worker "
                               f"process {where[1]}; its traceback there:\n{where[0]}")
            outcomes.append((index, kind, value))
        return outcomes

    def _stop(self, slot):
        """Kill the worker in `slot` (if it still runs) and free the slot."""
        worker, self._slots[slot] = self._slots[slot], None
        worker.process.kill()
        worker.process.join()
        worker.connection.close()

    def _abandon(self):
        for slot, worker in enumerate(self._slots):
            if worker is not None and worker.job is not None:
                self._stop(slot)

    def close(self):
        """Close the workers' connections, so that idle workers end, and kill any that do not
        within a few seconds."""
        for worker in self._slots:
            if worker is not None:
                worker.connection.close()
        for slot, worker in enumerate(self._slots):
            if worker is not None:
                worker.process.join(timeout=5)
                worker.process.kill()
                worker.process.join()
                self._slots[slot] = None


# ---------------------------------------------------------------------------------------------
# Ray


def _call(fn, args):
    """A Ray task: one job."""
    return _job(fn, args)


class RayExecutor(Executor):
    """Ray tasks, at most `workers` at once, each taking `cores_per_worker` CPUs; see the module
    docstring. When this process is already connected to Ray (`ray.init` was called), that
    connection is used and `address` is not; otherwise `address` None or "local" starts a Ray
    instance on this machine, which `close()` shuts down again."""

    def __init__(self, workers, address=None, cores_per_worker=1, max_retries=2):
        super().__init__(workers, max_retries)
        if importlib.util.find_spec("ray") is None:
            raise ExecutorError(RAY_MISSING)
        import ray

        self._ray = ray
        self._started_ray = not ray.is_initialized()
        if self._started_ray:
            try:
                if address in (None, "", "local"):
                    ray.init(address="local", include_dashboard=False)
                else:
                    ray.init(address=address)
            except Exception as error:       # Ray raises several kinds
                raise ExecutorError(f"cannot start or join Ray at address {address!r}: "
                                    f"{error}") from error
        # Ray runs a task again after its worker died by itself (max_retries); here the one
        # rule of Executor.map_unordered does, so Ray is told not to.
        self._task = ray.remote(_call).options(
            num_cpus=cores_per_worker, max_retries=0, retry_exceptions=False,
            runtime_env={"env_vars": thread_environment(cores_per_worker)})
        self._running = {}          # ObjectRef -> (index, fn, args)

    def _start(self, index, fn, args):
        try:
            reference = self._task.remote(fn, args)
        except Exception as error:
            raise ExecutorError(f"job {index} ({_describe(fn, args)}) cannot be sent to Ray: "
                                f"{error}") from error
        self._running[reference] = index, fn, args

    def _finished(self):
        exceptions = self._ray.exceptions
        lost = (exceptions.WorkerCrashedError, exceptions.NodeDiedError,
                exceptions.OutOfMemoryError, exceptions.LocalRayletDiedError)
        ready, _ = self._ray.wait(list(self._running), num_returns=1)
        outcomes = []
        for reference in ready:
            index, fn, args = self._running.pop(reference)
            try:
                outcomes.append((index, "result", self._ray.get(reference)))
            except exceptions.RayTaskError as error:
                cause = error.cause if isinstance(error.cause, BaseException) else error
                cause.add_note(f"raised by job {index} ({_describe(fn, args)}) in a Ray task; "
                               f"what Ray reported:\n{error}")
                outcomes.append((index, "error", cause))
            except lost as error:
                outcomes.append((index, "lost", f"Ray reported: {str(error).splitlines()[0]}"))
        return outcomes

    def _abandon(self):
        for reference in self._running:
            self._ray.cancel(reference, force=True)
        self._running.clear()

    def close(self):
        """Cancel the tasks still running and shut down the Ray instance this executor
        started."""
        self._abandon()
        if self._started_ray:
            self._ray.shutdown()
            self._started_ray = False


# ---------------------------------------------------------------------------------------------
# from a config


@dataclass(frozen=True)
class ExecutorSettings:
    """A config's `[executor]` table: where independent jobs run. Which executor runs them does
    not change their results, so a resumed run may change these."""
    backend: str = "local"          # "local": processes on this machine; "ray": a Ray cluster
    workers: int = 1                # jobs at once (local with 1: in this process)
    cores_per_worker: int = 0       # 0: local shares this machine's cores out evenly; ray: 1
    address: str = ""               # ray: "" or "local" (start one here), "auto", "ray://h:p"
    max_retries: int = 2            # runs again of a job whose worker process died

    def __post_init__(self):
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}; got "
                             f"{self.backend!r}")
        _check_counts(self.workers, self.max_retries)
        if self.cores_per_worker < 0:
            raise ValueError(f"cores_per_worker must be at least 0; got {self.cores_per_worker}")
        if self.backend == "local":
            if self.address:
                raise ValueError(f"address ({self.address!r}) names a Ray cluster; it needs "
                                 "backend = \"ray\"")
            worker_cores(self.workers, self.cores_per_worker or None)
        elif importlib.util.find_spec("ray") is None:
            raise ValueError(RAY_MISSING)


def executor_from(settings: ExecutorSettings) -> Executor:
    """The executor `settings` name: `InProcess` for one local worker, else `LocalProcesses` or
    `RayExecutor`."""
    if settings.backend == "ray":
        return RayExecutor(settings.workers, settings.address or None,
                           settings.cores_per_worker or 1, settings.max_retries)
    if settings.workers == 1:
        return InProcess()
    return LocalProcesses(settings.workers, settings.cores_per_worker or None,
                          settings.max_retries)
