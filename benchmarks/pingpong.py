"""Bare rclpy ping-pong between two processes: the ceiling of the DDS lockstep loop.

``ping``: publishes ``biped_msgs_py/msg/SimState`` on /bench/sim_state and, event-driven (inside the
subscription callback), the next one as soon as the ``sensor_msgs/msg/JointState`` answer arrives on
/bench/torque. ``pong``: answers each SimState with one JointState (6 efforts, like the controller's
torque message). Same QoS as the real lockstep topics (graph_names.QOS_LOCKSTEP). Both use a
SingleThreadedExecutor.

    python -m benchmarks.pingpong pong
    python -m benchmarks.pingpong ping --count N --warmup W    # prints one JSON line

Run both in an isolated domain (ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST).
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

STATE_TOPIC = "/bench/sim_state"
REPLY_TOPIC = "/bench/torque"


def _qos():
    from biped_sim.graph.names import QOS_LOCKSTEP
    return QOS_LOCKSTEP


def pong(timeout: float) -> int:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from biped_msgs_py.msg import SimState
    from sensor_msgs.msg import JointState

    rclpy.init()
    node = rclpy.create_node("bench_pong")
    pub = node.create_publisher(JointState, REPLY_TOPIC, _qos())
    names = ["j1", "j2", "j3", "j4", "j5", "j6"]
    state = {"last": time.monotonic()}

    def on_state(msg: SimState) -> None:
        out = JointState()
        out.header.stamp = msg.stamp
        out.header.frame_id = str(msg.sequence)
        out.name = names
        out.effort = [float(v) for v in msg.q]   # some work proportional to the real reply
        pub.publish(out)
        state["last"] = time.monotonic()

    node.create_subscription(SimState, STATE_TOPIC, on_state, _qos())
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    try:
        while rclpy.ok() and time.monotonic() - state["last"] < timeout:
            ex.spin_once(timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def ping(count: int, warmup: int, discovery_timeout: float) -> int:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from biped_msgs_py.msg import SimState
    from sensor_msgs.msg import JointState

    rclpy.init()
    node = rclpy.create_node("bench_ping")
    pub = node.create_publisher(SimState, STATE_TOPIC, _qos())
    rng = np.random.default_rng(0)
    qs = rng.normal(size=(64, 6))
    total = warmup + count
    rtt = np.zeros(total, dtype=np.int64)
    st = {"seq": 0, "sent": 0, "resent": 0, "done": False, "t_first": 0, "t_end": 0}

    def send() -> None:
        m = SimState()
        k = st["seq"]
        m.stamp.sec, m.stamp.nanosec = divmod(k, 1000)
        m.stamp.nanosec *= 1_000_000
        m.step = k
        m.stance = k & 1
        m.q = qs[k % 64].tolist()
        m.q_dot = qs[(k + 1) % 64].tolist()
        m.base = [0.0, 0.8, 0.0]
        m.base_dot = [0.5, 0.0, 0.0]
        m.sequence = k
        st["sent"] = time.perf_counter_ns()
        pub.publish(m)

    def on_reply(msg: JointState) -> None:
        if st["done"] or int(msg.header.frame_id) != st["seq"]:
            return
        now = time.perf_counter_ns()
        k = st["seq"]
        rtt[k] = now - st["sent"]
        if k == warmup:
            st["t_first"] = st["sent"]
        st["seq"] = k + 1
        if st["seq"] >= total:
            st["done"], st["t_end"] = True, now
            return
        send()

    node.create_subscription(JointState, REPLY_TOPIC, on_reply, _qos())
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    t0 = time.monotonic()
    while pub.get_subscription_count() < 1 or node.count_publishers(REPLY_TOPIC) < 1:
        ex.spin_once(timeout_sec=0.05)
        if time.monotonic() - t0 > discovery_timeout:
            print(json.dumps({"error": "discovery timeout"}))
            return 1
    time.sleep(0.3)   # let the reverse direction match too
    ex.spin_once(timeout_sec=0.05)
    send()
    last_seq, last_change = -1, time.monotonic()
    while not st["done"]:
        ex.spin_once(timeout_sec=0.2)
        if st["seq"] != last_seq:
            last_seq, last_change = st["seq"], time.monotonic()
        elif time.monotonic() - last_change > 0.5:   # lost message: resend the same sequence
            st["resent"] += 1
            send()
            last_change = time.monotonic()
            if st["resent"] > 50:
                print(json.dumps({"error": "too many lost messages", "done": st["seq"]}))
                return 1
    r = rtt[warmup:] / 1000.0
    wall = (st["t_end"] - st["t_first"]) / 1e9
    print(json.dumps({"round_trips": int(count), "wall_s": wall, "rate_hz": count / wall,
                      "rtt_p50_us": float(np.percentile(r, 50)), "rtt_p99_us": float(np.percentile(r, 99)),
                      "rtt_max_us": float(r.max()), "resent": st["resent"]}))
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("role", choices=["ping", "pong"])
    ap.add_argument("--count", type=int, default=5000)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--timeout", type=float, default=20.0)
    a = ap.parse_args(argv)
    if a.role == "pong":
        return pong(a.timeout)
    return ping(a.count, a.warmup, a.timeout)


if __name__ == "__main__":
    sys.exit(main())
