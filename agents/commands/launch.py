"""`takeoff train … --processes N`: one training run as N processes on this host.

The launcher starts N copies of the same `takeoff train` command, each joining one
`jax.distributed` run as process i of N, with process 0 as the coordinator on a free localhost
port (`--coordinator 127.0.0.1:PORT --num-processes N --process-id i`: the flags a cluster's
job script gives each machine's process itself). Where this process may run on at least two
cores per child, each child is pinned to its own share of them (`MIN_CORES_PINNED`: one core
per process slows every collective operation). Process 0's output is the run's; the
others' is kept, and shown when one of them is the first to fail.

Stopping: a Ctrl-C or a SIGTERM reaches the launcher only (the children run in their own
sessions); it passes the signal on to each child once, and the children stop together after
an iteration, process 0 saving a checkpoint (`parallel.Stop`). A second one kills them. The
launcher's handler only notes a signal and its wait loop acts on it: an exception raised from a
handler lands wherever the interpreter happens to be, and is lost where it lands inside a
garbage-collector callback or a finaliser (Python only prints it there). A child
that fails ends the others (they would wait for it forever), and a child whose launcher dies
is killed by the kernel (PR_SET_PDEATHSIG, on Linux). The launcher's exit status is the first
failing child's (a child ended by a signal counts as 128 + its number; after a Ctrl-C or
SIGTERM the children stop as interrupted, 130), else 0; after a second stop signal, 128 + the
first's number unless a child had failed.

This module imports no JAX: the launcher starts no backend of its own.
"""

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time

from jaxsim.executor import end_with_parent

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
GRACE_SECONDS = 10.0       # how long the others may take to fail by themselves when one fails
# A process pinned to a single core waits ~8× longer for each collective operation (3.8 ms
# against 0.5 ms for a small all-reduce over gloo, 2 processes on the 2-core machine): its
# compute thread and gloo's I/O threads share the core. So a process is pinned only when it
# gets at least this many cores.
MIN_CORES_PINNED = 2


def free_port() -> int:
    """A TCP port free on localhost now (the coordinator binds it a moment later)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def core_shares(processes: int, minimum: int = MIN_CORES_PINNED) -> list:
    """The cores each process is pinned to: this process's cores in `processes` contiguous
    shares, or None for each (not pinned) when a share would have fewer than `minimum` cores
    (or there is no affinity to set)."""
    try:
        cores = sorted(os.sched_getaffinity(0))
    except AttributeError:
        return [None] * processes
    if len(cores) < minimum * processes:
        return [None] * processes
    size, extra = divmod(len(cores), processes)
    shares, start = [], 0
    for i in range(processes):
        end = start + size + (i < extra)
        shares.append(cores[start:end])
        start = end
    return shares


def _child_setup(cores):
    """In the child, before it runs: die with the launcher; run on its own cores."""
    end_with_parent(signal.SIGKILL)
    if cores:
        os.sched_setaffinity(0, cores)


def child_commands(train_args, processes: int, port: int) -> list:
    """The command line of each process: `takeoff train` with `train_args` and its place."""
    base = [sys.executable, "-m", "agents.commands.cli", "train", *train_args,
            "--coordinator", f"127.0.0.1:{port}", "--num-processes", str(processes)]
    return [[*base, "--process-id", str(i)] for i in range(processes)]


def launch(train_args, processes: int, echo=print) -> int:
    """Run `takeoff train` with `train_args` as `processes` processes of one run on this host;
    the exit status (see the module docstring)."""
    port = free_port()
    shares = core_shares(processes)
    pinned = "" if shares[0] is None else ", each on its own cores"
    echo(f"takeoff train: {processes} processes on this host{pinned} (coordinator "
         f"127.0.0.1:{port})", flush=True)
    received = []                       # the stop signals that reached the launcher, in order
    previous = {stop: signal.signal(stop, lambda signum, frame: received.append(signum))
                for stop in STOP_SIGNALS}
    children, logs, failed = [], [], []
    status = 1
    try:
        for i, (command, cores) in enumerate(zip(child_commands(train_args, processes, port),
                                                 shares)):
            # process 0's output is the run's; the others' is kept, to be shown if one of
            # them is the first to fail
            log = None if i == 0 else tempfile.TemporaryFile()
            logs.append(log)
            children.append(subprocess.Popen(
                command, stdout=log, stderr=None if log is None else subprocess.STDOUT,
                start_new_session=True, preexec_fn=lambda c=cores: _child_setup(c)))
        status = _wait(children, failed, received, echo)
    finally:
        for child in children:          # whatever happened, no child outlives the launcher
            if child.poll() is None:
                child.kill()
                child.wait()
        if failed and failed[0] > 0 and not received:
            _show(logs[failed[0]], failed[0], echo)
        for log in logs:
            if log is not None:
                log.close()
        for stop, handler in previous.items():     # last: a Ctrl-C until here is only noted
            signal.signal(stop, handler)
    return status


def _show(log, index, echo, lines=60):
    """The last `lines` of a process's output, on standard error."""
    log.seek(0)
    text = log.read().decode("utf-8", "replace").splitlines()[-lines:]
    echo(f"takeoff train: process {index} failed first; its output:", file=sys.stderr)
    echo("\n".join(text), file=sys.stderr, flush=True)


def _wait(children, failed, received, echo) -> int:
    """Wait for all children; the first non-zero status, else 0 (and the index of the first
    child to fail appended to `failed`). After a child fails (other than by a Ctrl-C, after
    which the others finish their checkpoint), the others get `GRACE_SECONDS` to end by
    themselves (a failure in all of them, with its message), then are killed (one waiting for
    a dead process in a collective operation would wait forever; JAX's runtime takes SIGTERM
    as a preemption notice, so only SIGKILL ends it).

    `received` is the launcher's list of stop signals, appended to by its handler: the first
    is passed on to the children (who then end as interrupted, 130, or, where it came before
    their handlers were set, are ended by it: 128 + its number); a second kills the children
    and ends the wait with 128 + the first's number unless a child had failed."""
    status, failed_at, stopped_by = 0, None, None
    while True:
        if received and stopped_by is None:
            stopped_by = received[0]
            echo("\ntakeoff train: stopping all processes after their iteration, with a "
                 "checkpoint (Ctrl-C again kills them)", file=sys.stderr, flush=True)
            _signal(children, stopped_by)
        if len(received) > 1:
            _signal(children, signal.SIGKILL)
            return status or 128 + stopped_by
        codes = [_status(child.poll()) for child in children]
        for index, code in enumerate(codes):
            if code and not status:
                status = code
                failed.append(index)
                failed_at = time.monotonic() if code != 130 else None
        if all(code is not None for code in codes):
            return status or (0 if stopped_by is None else 128 + stopped_by)
        if failed_at is not None and time.monotonic() - failed_at > GRACE_SECONDS:
            _signal(children, signal.SIGKILL)
            return status
        time.sleep(0.1)


def _status(code):
    """A child's exit status as a shell gives it: 128 + the number of the signal that ended it
    (Popen's negative codes), its exit code otherwise (None while it runs)."""
    return 128 - code if code is not None and code < 0 else code


def _signal(children, signum):
    for child in children:
        if child.poll() is None:
            try:
                child.send_signal(signum)
            except ProcessLookupError:
                pass
