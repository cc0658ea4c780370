"""The recorder and the Foxglove bridge in one process (``scripts/launch --live``, ``bridge.host_process: recorder``).

Executable ``live_recorder``: the node ``recorder`` (:class:`biped_sim.graph.recorder_node.RecorderNode`, its
parameters, bag and exit status unchanged) and, as a companion in the same process and executor, the node
``bridge`` (:class:`biped_sim.live.bridge_node.BridgeNode` with ``subscribe=False``: its server, channels,
sim time and ``/apply_push`` service, its parameters from the ``bridge:`` section). The bridge has no DDS reader
of its own: every message the recorder takes is handed to it (``RecorderNode.taps``, in the recorder's thread,
in the order the recorder records: publication order within a batch; each batch just before it is written, so a
chunk compressed meanwhile does not delay its frames), so one reader per topic serves both the MCAP and the
WebSocket. ROS 2's composition (several nodes in one process) is the
precedent.

Why (docs/live_view.md): with the bridge in its own process, every per-step topic has one more
reader, and each reader costs the simulator and the controller a write (Fast DDS's per-reader cost dominated what
remained of their publish), plus the bridge process's own take of every message (Python thread, Fast DDS's
receive thread). Co-hosted, the bridge's work per message is ``Channel.log`` only.

Failure isolation is the price: the live view is not a separate process that may die while the run goes on.
A server that cannot start (port in use) is reported and the recorder records without the live view
(exit status as the recorder's); a bridge parameter that is invalid exits 2 naming it, as the bridge's own
executable does, before any file is created.
"""
from __future__ import annotations

import sys
from typing import List, Optional

from biped_sim.graph.params import run_node
from biped_sim.graph.recorder_node import RecorderNode
from biped_sim.live.bridge_node import BridgeNode, BridgeStartError
from biped_sim.recording.mcap_recorder import RecorderError


class LiveRecorderNode(RecorderNode):
    """The recorder with a co-hosted :class:`BridgeNode` (module docstring). ``companions`` holds the bridge for
    ``run_node`` (added to the same executor, destroyed at the end).

    :raises ParameterError: a recorder or bridge parameter is invalid (nothing is started: the bridge is built
        first, so a bad bridge parameter creates no bag).
    :raises RecorderError: the bag cannot be created.
    """

    def __init__(self, **kwargs) -> None:
        self.bridge: Optional[BridgeNode] = None
        bridge_error = None
        try:
            bridge = BridgeNode(subscribe=False)
        except BridgeStartError as exc:   # the run records on without the live view
            bridge, bridge_error = None, exc
        try:
            super().__init__(**kwargs)
        except BaseException:
            if bridge is not None:
                bridge.server.stop()
                bridge.destroy_node()
            raise
        self._bridge_error = bridge_error
        self.bridge = bridge
        self.companions = [] if bridge is None else [bridge]
        if bridge is not None:
            self.taps.append(bridge.tap)

    def spinner(self, executor):
        """The recorder's loop (``run_node`` calls this once its stop handlers are installed: the log line
        below also says the node now stops cleanly on SIGINT/SIGTERM)."""
        if self._bridge_error is not None:
            self.get_logger().error(f'{self._bridge_error}: recording without the live view')
        return super().spinner(executor)

    def after_spin(self, executor, signum) -> int:
        """The recorder drains and finishes its bag (the bridge serving what it drains), then the server stops."""
        try:
            return super().after_spin(executor, signum)
        finally:
            if self.bridge is not None:
                self.bridge.after_spin(executor, signum)


def main(args: Optional[List[str]] = None) -> int:
    return run_node('live_recorder', LiveRecorderNode, args, startup_errors=(RecorderError,))


if __name__ == '__main__':
    sys.exit(main())
