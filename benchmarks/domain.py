"""The one ROS 2 domain helper of the benchmarks that start nodes (``benchmarks.dds``, ``lockstep``,
``bridge_bench``, ``publish_cost``, ``imu_lockstep`` and the lab's graph benchmarks)."""
from __future__ import annotations

import os

from benchmarks.common import ROOT


class Domain:
    """A free ROS_DOMAIN_ID from domain_coordinator (port lock) for the duration of the block."""

    def __enter__(self):
        self._cm = None
        try:
            from domain_coordinator import domain_id
            self._cm = domain_id()
            did = self._cm.__enter__()
        except Exception:  # noqa: BLE001
            did = 101 + os.getpid() % 100
        env = dict(os.environ)
        env.update(ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        env.pop("ROS_STATIC_PEERS", None)
        env.pop("ROS_LOCALHOST_ONLY", None)
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        self.env, self.id = env, did
        return self

    def __exit__(self, *exc):
        if self._cm is not None:
            self._cm.__exit__(*exc)
