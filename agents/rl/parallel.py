"""Data-parallel training: one run's environments split over devices and over processes.

One code path for one device, several local devices and several processes. The trainer's two
programs are compiled over a `Mesh` of the run's devices (one axis, `AXIS`): the arrays with an
environment axis (the environments, their per-step samples) are split along it, everything else
(networks, optimiser states, observation statistics, keys, curriculum) is replicated. The
programs are the single-device programs, partitioned by XLA:

- the environments step where they live: the simulator's step runs per shard (`per_shard`, a
  `shard_map`, so `batch_last`'s chunks are each device's own), and the policy, the action noise
  and the resets around it are partitioned along the batch with no communication (the compiled
  rollout has no collective operation: tests/test_parallel_training.py);
- the observation statistics, the advantages' targets and the episode means are reductions over
  the whole batch (XLA sums the shards' partial sums);
- the PPO update shuffles the whole batch, as on one device, and spreads each minibatch's samples
  over the devices (`spread_samples`): each device computes the gradient of its share and the
  shares are summed, so the gradients are averaged over the devices.

So N devices compute what one device computes, up to the order of floating-point sums, and a
checkpoint does not depend on how the run was split.

Processes (`Cluster`, `start`): JAX's multi-controller runtime, `jax.distributed` (on the CPU its
collectives are gloo's, over TCP). Every process runs the same programs on global arrays, each
stepping its own share of the environments; all start from process 0's state (`place`), only
process 0 writes the run directory, and a checkpoint is gathered to the host (`host`) as an
ordinary single-process one. What ends a multi-process run between iterations (a Ctrl-C, a
SIGTERM, the time limit) is agreed by all processes (`Stop`), so they stop at the same
iteration.
"""

import os
import signal
from dataclasses import dataclass

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from agents.config import ConfigError
from jaxsim import simulation

AXIS = "envs"          # the mesh axis the environment batch is split along
DEVICE_COUNT_FLAG = "xla_force_host_platform_device_count"
MAX_CPU_DEVICES = 1024     # the most host devices `start` asks for (beyond: `mesh` refuses)


@dataclass(frozen=True)
class Cluster:
    """How this process joins a multi-process run: the coordinator's HOST:PORT (where process 0
    listens; every process must reach it), the number of processes and this one's index; with
    `coordinator` "auto", all three come from the cluster's environment (JAX's cluster
    detection: SLURM, Open MPI, Kubernetes, …)."""

    coordinator: str = "auto"
    num_processes: int | None = None
    process_id: int | None = None


def cpu_cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:                     # not Linux
        return os.cpu_count() or 1


def _backend_started() -> bool:
    from jax._src import xla_bridge
    return xla_bridge.backends_are_initialized()


def start(devices: int, cluster: Cluster | None = None):
    """Before JAX's backend starts: join `cluster` (`jax.distributed.initialize`), and give
    the CPU backend `devices` devices (0: one per core this process may run on; one in a
    process of a multi-process run that is not pinned to cores of its own), unless
    XLA_FLAGS or `jax_num_cpu_devices` already chose a number. Once the backend has started,
    neither can change (`mesh` then says what is missing)."""
    if cluster is not None and not jax.distributed.is_initialized():
        if _backend_started():
            raise RuntimeError("a process joins a multi-process run before JAX's backend "
                               "starts; something ran a JAX computation first")
        if cluster.coordinator == "auto":
            jax.distributed.initialize()
        else:
            jax.distributed.initialize(cluster.coordinator, cluster.num_processes,
                                       cluster.process_id)
    wanted = devices or cpu_cores()
    if cluster is not None and not devices and cpu_cores() == (os.cpu_count() or 1):
        wanted = 1        # a process not pinned to its own cores shares them with the others
    from jax._src import xla_bridge
    if (1 < wanted <= MAX_CPU_DEVICES and not _backend_started()
            and xla_bridge.num_cpu_devices.value < 0
            and DEVICE_COUNT_FLAG not in os.environ.get("XLA_FLAGS", "")):
        jax.config.update("jax_num_cpu_devices", wanted)


def mesh(devices: int = 1) -> Mesh:
    """The run's devices as a one-axis mesh: on each process its first `devices` local devices
    (0: all of them), process by process. A ConfigError when this process has fewer."""
    local = jax.local_devices()
    if len(local) < devices:
        started = ("; a process's CPU devices are fixed when its JAX backend starts: "
                   f"`takeoff train` asks for run.devices unless XLA_FLAGS chose a number, and "
                   f"elsewhere start Python with XLA_FLAGS=--{DEVICE_COUNT_FLAG}={devices}"
                   if local[0].platform == "cpu" else "")
        raise ConfigError(f"run.devices = {devices}, but this process has {len(local)} "
                          f"{local[0].platform} device{'s' if len(local) > 1 else ''}{started}")
    chosen = []
    for process in range(jax.process_count()):
        own = sorted((d for d in jax.devices() if d.process_index == process),
                     key=lambda d: d.id)
        chosen += own[:devices or None]
    return Mesh(np.array(chosen), (AXIS,))


def first_device(mesh_: Mesh) -> Mesh:
    """A one-device mesh of the first device of `mesh_`."""
    return Mesh(np.asarray(mesh_.devices).ravel()[:1], (AXIS,))


def describe(mesh_: Mesh) -> str:
    """How a run is split, for its first line: "" on one device."""
    if mesh_.size == 1:
        return ""
    processes = jax.process_count()
    if processes == 1:
        return f", split over {mesh_.size} devices"
    return f", split over {mesh_.size} devices in {processes} processes"


def check_split(envs: int, mesh_: Mesh, devices: int) -> str | None:
    """Why `envs` environments cannot be split evenly over the mesh (None when they can),
    naming both numbers."""
    if envs % mesh_.size == 0:
        return None
    processes = jax.process_count()
    over = (f"{processes} processes × " if processes > 1 else "")
    return (f"run.envs = {envs} cannot be split evenly over the run's {mesh_.size} devices "
            f"({over}run.devices = {devices}{' (all local ones)' if devices == 0 else ''}); "
            f"make it a multiple of {mesh_.size}")


class Layout:
    """Shardings over a run's mesh: `envs` (the environment batch on axis 0), `steps` (time-major
    (T, N, …) samples: the batch on axis 1) and `replicated`."""

    def __init__(self, mesh_: Mesh):
        self.mesh = mesh_
        self.size = mesh_.size
        self.envs = NamedSharding(mesh_, PartitionSpec(AXIS))
        self.steps = NamedSharding(mesh_, PartitionSpec(None, AXIS))
        self.replicated = NamedSharding(mesh_, PartitionSpec())

    def per_shard(self, batched, in_axes):
        """`batched` computed by each device on its own shard of the batch
        (`jaxsim.simulation.per_shard` over the run's mesh): for per-environment work."""
        return simulation.per_shard(batched, self.mesh, in_axes)

    def spread_samples(self, minibatches):
        """PPO's shuffled minibatches (n_minibatches, minibatch, …) with each minibatch's
        samples spread over the devices: each computes its share's gradient, and XLA sums them."""
        return jax.lax.with_sharding_constraint(minibatches, self.steps)

    def place(self, tree, shardings):
        """`tree` (host or single-device values) as arrays laid out by `shardings` (a pytree
        prefix of it) over the run's devices; across processes, with process 0's values (every
        process starts from the state that process 0 made or read)."""
        full = _expand(shardings, tree)
        if jax.process_count() == 1:
            return jax.device_put(tree, full)
        return _from_process_0(tree, full, self.mesh)

    def host(self, tree):
        """`tree`'s values as numpy arrays on the host, gathered from every process (all
        processes must call it, at the same point)."""
        if jax.process_count() == 1:
            return jax.device_get(tree)
        gathered = jax.jit(_identity, out_shardings=self.replicated)(tree)
        return jax.tree_util.tree_map(lambda x: np.asarray(x.addressable_data(0)), gathered)


def lay_out(tree, shardings):
    """`tree`'s arrays laid out by `shardings` (a pytree prefix of it) on this process's
    devices: copies only of the arrays laid out otherwise."""
    return jax.device_put(tree, _expand(shardings, tree))


def _identity(tree):
    return tree


def _expand(prefix, tree):
    """The sharding of every leaf of `tree`, from a pytree prefix of it."""
    return jax.tree_util.tree_map(
        lambda sharding, subtree: jax.tree_util.tree_map(lambda _: sharding, subtree),
        prefix, tree)


def _first(tree):
    return jax.tree_util.tree_map(lambda x: x[0], tree)


def _from_process_0(tree, shardings, mesh_: Mesh):
    """Each leaf stacked over the processes (each process's slot holding its own value), then
    one program takes process 0's slot and lays it out by `shardings`."""
    processes = jax.process_count()
    grid = Mesh(np.asarray(mesh_.devices).reshape(processes, -1), ("processes", "local"))
    stacked_sharding = NamedSharding(grid, PartitionSpec("processes"))

    def stacked(x):
        local = np.asarray(jax.device_get(x))[None]
        return jax.make_array_from_process_local_data(stacked_sharding, local,
                                                      (processes, *local.shape[1:]))

    return jax.jit(_first, out_shardings=shardings)(jax.tree_util.tree_map(stacked, tree))


def is_writer() -> bool:
    """Whether this process writes the run directory and shows progress (process 0)."""
    return jax.process_index() == 0


def process_label() -> str:
    """" (process i)" in a process other than the first of a multi-process run, else ""."""
    if not jax.distributed.is_initialized() or jax.process_index() == 0:
        return ""
    return f" (process {jax.process_index()})"


class Stop:
    """What ends a run between iterations. In a multi-process run it is decided by all the
    processes together (`agreed`): a Ctrl-C (SIGINT) that reached any of them (between `listen`
    and `close` a handler only notes it), a SIGTERM (JAX's preemption service, which
    `jax.distributed` starts, notes it and names the iteration all stop after), or a time
    limit that any of them reached. In one process a Ctrl-C raises KeyboardInterrupt where it
    lands, and a SIGTERM (a batch system's preemption, `kill`) is noted and stops the run after
    the iteration it arrived in, as a Ctrl-C does; a second SIGTERM goes to the handler there
    was before (by default it ends the process at once)."""

    def __init__(self):
        self.many = jax.process_count() > 1
        self.interrupted = False
        self._previous = {}                # {signal: the handler `listen` replaced}

    def listen(self) -> "Stop":
        """Until `close`: note SIGINT (in a multi-process run) or SIGTERM (in one process)
        instead of acting on it where it lands."""
        noted = signal.SIGINT if self.many else signal.SIGTERM
        try:
            self._previous[noted] = signal.signal(noted, self._note)
        except ValueError:                 # not the main thread: signals are not ours
            pass
        return self

    def close(self):
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous = {}

    def noted_alone(self) -> bool:
        """Whether this process, alone in its run, noted a SIGTERM (after the run's last
        `agreed`, too: the caller's next run must not start)."""
        return self.interrupted and not self.many

    def _note(self, signum, frame):
        self.interrupted = True
        if signum == signal.SIGTERM:       # a second one is not waited on
            signal.signal(signum, self._previous.pop(signum, signal.SIG_DFL))

    def agreed(self, iteration: int, time_up: bool) -> tuple[bool, bool]:
        """After `iteration`: (whether the run stops as interrupted, by a Ctrl-C or SIGTERM
        that reached any process, or a SIGTERM noted in one; whether any process reached the
        time limit)."""
        if not self.many:
            return self.interrupted, bool(time_up)
        from jax.experimental import multihost_utils
        flags = multihost_utils.process_allgather(
            np.array([self.interrupted, bool(time_up)], np.int32))
        try:
            preempted = multihost_utils.reached_preemption_sync_point(iteration)
        except RuntimeError:               # the preemption service is off
            preempted = False
        return bool(flags[:, 0].any()) or preempted, bool(flags[:, 1].any())
