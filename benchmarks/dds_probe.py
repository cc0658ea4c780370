"""The bridge benchmark's plain DDS subscriber, in a process of its own (``benchmarks.bridge_bench``).

    .venv/bin/python -m benchmarks.dds_probe --ready FILE --first FILE --out FILE   (ROS_DOMAIN_ID from the environment)

A raw ``/sim/state`` subscription with the recorder's QoS on rclpy's ``SingleThreadedExecutor``; for every message
(receive ``time.time_ns()``, DDS source timestamp ns). ``--ready`` is written once the subscription exists,
``--first`` at the first message (the benchmark starts its CPU accounting then); on SIGINT or SIGTERM the rows go to
``--out`` as JSON and the process exits 0.

Why a process of its own: as a thread of the benchmark's process it shared the WebSocket client's
interpreter lock; its Python work on every message (an executor round and a callback at 1 kHz) held the client's
reads back, by tens of milliseconds at times (traced: the client's socket receive queue grew to 140 kB while the
server's frames had left), and those were counted as the bridge's latency.
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='dds_probe', description=__doc__.split('\n\n')[0])
    ap.add_argument('--ready', type=Path, required=True)
    ap.add_argument('--first', type=Path, required=True)
    ap.add_argument('--out', type=Path, required=True)
    a = ap.parse_args(argv)
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from biped_sim.graph import names as gn
    from biped_sim.graph.recorder_node import recording_qos

    stop = {'now': False}
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.__setitem__('now', True))
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('bridge_bench_probe')
    rows: list[tuple[int, int]] = []
    spec = gn.TOPICS[gn.SIM_STATE]

    def on_msg(_msg: bytes, info) -> None:
        rows.append((time.time_ns(), int(info['source_timestamp'])))
        if len(rows) == 1:
            a.first.write_text('1')

    node.create_subscription(spec.msg_class(), spec.name, on_msg, recording_qos(spec.qos_profile), raw=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    a.ready.write_text('1')
    try:
        while not stop['now']:
            executor.spin_once(timeout_sec=0.05)
    finally:
        a.out.write_text(json.dumps(rows))
        node.destroy_node()
        rclpy.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
