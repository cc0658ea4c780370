"""The shared executors (``closed_loop.executor``) bound to the map's task: a batch of simulations
(:func:`task.simulate_batch`), each worker loading its models once (:func:`task.worker_init`)."""
from __future__ import annotations

from biped_controller.closed_loop import executor as _ex
from biped_controller.studies.capmap.task import simulate_batch, worker_init

#: simulations per task by executor: 1 on the pool, 4 on Ray (a failing simulation takes ~0.1 s, less
#: than Ray's per-task overhead pays for)
DEFAULT_BATCH = {"pool": 1, "ray": 4}


class SerialExecutor(_ex.SerialExecutor):
    """In this process; ``task`` replaces the simulation (the tests' synthetic survival functions)."""

    def __init__(self, task=simulate_batch):
        super().__init__(task)


class PoolExecutor(_ex.PoolExecutor):
    def __init__(self, workers: int, task=simulate_batch):
        super().__init__(workers, task, worker_init)


class RayExecutor(_ex.RayExecutor):
    def __init__(self, address: str | None, workers: int, task=simulate_batch):
        super().__init__(address, workers, task)


def make_executor(workers: int, ray: str | None = None):
    """Ray (``ray`` "local" or an address), a pool of ``workers`` processes, or this process (1)."""
    if ray is not None:
        return RayExecutor(None if ray == "local" else ray, workers)
    return SerialExecutor() if workers == 1 else PoolExecutor(workers)
