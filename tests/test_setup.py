"""Checks of scripts/setup: imports, the ros2-run layout, a real ApplyPush service round trip
between two processes, and that a second setup run installs nothing."""

import math
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
VENV = Path(sys.prefix)


def test_imports():
    import mcap  # noqa: F401
    import pinocchio  # noqa: F401
    import piqp  # noqa: F401
    import rclpy  # noqa: F401
    from biped_msgs_py.msg import ControllerStatus, PushEvent, SimState
    from biped_msgs_py.srv import ApplyPush
    from tf2_msgs.msg import TFMessage

    status = ControllerStatus()
    assert len(status.margins) == ControllerStatus.NUM_MARGINS == 17
    assert [ControllerStatus.QP_UNCONSTRAINED, ControllerStatus.QP_ACTIVE,
            ControllerStatus.QP_INFEASIBLE_FALLBACK, ControllerStatus.QP_SOLVER_ERROR,
            ControllerStatus.NO_ADAPTATION] == [0, 1, 2, 3, 4]
    state = SimState()
    assert len(state.q) == len(state.q_dot) == 6 and len(state.base) == len(state.base_dot) == 3
    assert set(PushEvent.get_fields_and_field_types()) == {'id', 'start', 'duration', 'force', 'height'}
    assert set(ApplyPush.Request.get_fields_and_field_types()) == {
        'force', 'duration', 'start', 'use_delay', 'delay', 'height'}
    assert set(ApplyPush.Response.get_fields_and_field_types()) == {
        'accepted', 'message', 'push_id', 'scheduled_start', 'scheduled_end'}
    assert TFMessage.get_fields_and_field_types() == {
        'transforms': 'sequence<geometry_msgs/TransformStamped>'}
    # NaN (default height) survives the message field
    assert math.isnan(ApplyPush.Request(height=float('nan')).height)


def test_message_definitions_installed_for_mcap_schemas():
    for rel in ['share/biped_msgs_py/msg/SimState.msg', 'share/biped_msgs_py/msg/ControllerStatus.msg',
                'share/biped_msgs_py/msg/PushEvent.msg', 'share/biped_msgs_py/srv/ApplyPush.srv',
                'share/tf2_msgs/msg/TFMessage.msg', 'share/biped_msgs_py/msg/SimState.json']:
        assert (VENV / rel).is_file(), rel


def test_graph_names_types_resolve():
    from biped_sim.graph import names as g
    for spec in g.TOPICS.values():
        cls = spec.msg_class()
        assert cls.__name__ == spec.type.rsplit('/', 1)[1]
        assert spec.qos_profile.depth == g.QOS_SPECS[spec.qos]['depth']
        assert g.offered_qos_profiles(spec.name)[0]['reliability'] == 'reliable'
    assert g.message_class(g.APPLY_PUSH_TYPE).Request is not None
    assert g.QOS_SPECS[g.TOPICS[g.ROBOT_DESCRIPTION].qos]['durability'] == 'transient_local'
    assert g.QOS_SPECS[g.TOPICS[g.PUSH_EVENTS].qos]['depth'] == 100


def test_ros2_run_layout_and_ament_index():
    from ament_index_python.packages import get_package_prefix, get_package_share_directory
    expected = {'biped_sim': ['simulator', 'disturbance', 'recorder'], 'biped_controller': ['controller']}
    for pkg, exes in expected.items():
        assert get_package_prefix(pkg) == str(VENV)
        assert Path(get_package_share_directory(pkg), 'package.xml').is_file()
        for exe in exes:
            path = VENV / 'lib' / pkg / exe
            assert path.is_file() and os.access(path, os.X_OK), path
    for pkg in ['biped_msgs_py', 'tf2_msgs', 'std_msgs', 'rosgraph_msgs']:
        assert get_package_prefix(pkg) == str(VENV)


def test_package_xml_pass_catkin_pkg():
    from catkin_pkg.package import parse_package
    for d in ['src/biped_msgs_py', 'src/biped_msgs_py/tf2_msgs_stub', 'src/biped_sim', 'src/biped_controller']:
        warnings = []
        pkg = parse_package(str(ROOT / d / 'package.xml'), warnings=warnings)
        assert pkg.package_format == 3 and not warnings, (d, warnings)


SERVER = textwrap.dedent('''
    import math, sys, time
    import rclpy
    from biped_msgs_py.srv import ApplyPush

    rclpy.init()
    node = rclpy.create_node('push_server_test')
    served = []

    def handle(req, res):
        res.accepted = req.duration > 0.0
        res.message = 'ok' if res.accepted else 'duration must be > 0'
        res.push_id = len(served) + 1
        res.scheduled_start = (1.0 + req.delay) if req.use_delay else req.start
        res.scheduled_end = res.scheduled_start + req.duration
        served.append(req)
        return res

    node.create_service(ApplyPush, '/apply_push', handle)
    print('READY', flush=True)
    deadline = time.monotonic() + 60.0
    while len(served) < 2 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    # let the last response go out
    end = time.monotonic() + 0.5
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    node.destroy_node()
    rclpy.shutdown()
    sys.exit(0 if len(served) == 2 else 3)
''')


@pytest.mark.ros
def test_apply_push_service_round_trip_two_processes(ros_domain, ros_env, tmp_path):
    import rclpy
    import rclpy.executors
    from biped_msgs_py.srv import ApplyPush

    assert ros_env['ROS_DOMAIN_ID'] == str(ros_domain)
    assert ros_env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    script = tmp_path / 'server.py'
    script.write_text(SERVER)
    server = subprocess.Popen([sys.executable, str(script)], env=ros_env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True)
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        assert server.stdout.readline().strip() == 'READY'
        node = rclpy.create_node('push_client_test', context=context)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        client = node.create_client(ApplyPush, '/apply_push')
        assert client.wait_for_service(timeout_sec=30.0), 'service not discovered'

        def call(req):
            t0 = time.monotonic()
            future = client.call_async(req)
            executor.spin_until_future_complete(future, timeout_sec=20.0)
            assert future.done(), 'no response'
            return future.result(), time.monotonic() - t0

        res, dt = call(ApplyPush.Request(force=40.0, duration=0.1, start=2.5, use_delay=False,
                                         delay=0.0, height=float('nan')))
        assert res.accepted and res.message == 'ok' and res.push_id == 1
        assert res.scheduled_start == pytest.approx(2.5)
        assert res.scheduled_end == pytest.approx(2.6)
        res, _ = call(ApplyPush.Request(force=-10.0, duration=0.0, use_delay=True, delay=0.5,
                                        height=0.2))
        assert not res.accepted and res.push_id == 2 and 'duration' in res.message
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
        try:
            out, _ = server.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
            out, _ = server.communicate()
    assert server.returncode == 0, out


@pytest.mark.slow
def test_second_setup_run_installs_nothing():
    proc = subprocess.run(['bash', str(ROOT / 'scripts' / 'setup')], capture_output=True, text=True,
                          timeout=900)
    # A first run may legitimately do work (e.g. a concurrent edit of a package.xml); the
    # run after it must not.
    if proc.returncode == 0 and 'nothing to do' not in proc.stdout:
        proc = subprocess.run(['bash', str(ROOT / 'scripts' / 'setup')], capture_output=True,
                              text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert lines[-1].startswith('setup: nothing to do'), proc.stdout
    steps = [ln for ln in lines if ln.startswith('setup: ') and '[' in ln]
    assert steps and all(': skip' in ln for ln in steps), proc.stdout
    # how long the no-op run takes is measured in the benchmarks, not asserted here
