"""Shared pytest fixtures.

``ros_domain``: an isolated ROS 2 graph for one test. It reserves a ROS_DOMAIN_ID (1..100) with
``domain_coordinator`` (a port lock, so concurrent test runs on this machine never share one;
fallback: derived from the pid), sets ``ROS_DOMAIN_ID`` and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
in ``os.environ`` for the duration of the test (so ``rclpy.init()`` in the test process and any
subprocess started with the default environment join it), and yields the id.

``ros_env``: a copy of ``os.environ`` for subprocesses, inside that domain.

``rclpy_context``: an initialised ``rclpy.Context`` in that domain, shut down afterwards.
"""

import os
import random

import pytest


def pytest_configure(config):
    config.addinivalue_line('markers', 'slow: takes more than a few seconds (deselect with -m "not slow")')
    config.addinivalue_line('markers', 'ros: starts ROS 2 nodes (uses the ros_domain fixture)')


class _PidSelector:
    """Start the search at a pid-derived id, so parallel runs rarely probe the same ids."""

    def __init__(self):
        self._value = (os.getpid() + random.randrange(100)) % 100

    def __call__(self):
        value = (self._value % 100) + 1
        self._value += 1
        return value


@pytest.fixture
def ros_domain(monkeypatch):
    try:
        from domain_coordinator import domain_id
    except ImportError:  # pragma: no cover - the wheel is in requirements.txt
        domain_id = None
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.delenv('ROS_STATIC_PEERS', raising=False)
    monkeypatch.delenv('ROS_LOCALHOST_ONLY', raising=False)
    if domain_id is None:
        did = 1 + (os.getpid() % 100)
        monkeypatch.setenv('ROS_DOMAIN_ID', str(did))
        yield did
        return
    with domain_id(selector=_PidSelector()) as did:
        monkeypatch.setenv('ROS_DOMAIN_ID', str(did))
        yield did


@pytest.fixture
def ros_env(ros_domain):
    return dict(os.environ)


@pytest.fixture
def rclpy_context(ros_domain):
    import rclpy
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        if context.ok():
            rclpy.shutdown(context=context)


@pytest.fixture(scope='session')
def ray_session():
    """One local Ray instance (2 CPUs, no dashboard) for the whole run, shut down at its end: the tests that
    compare Ray with the process pool share it (starting Ray and its workers costs seconds each time). The
    executors find it connected, so they neither start nor stop it (``RayExecutor.owned`` is False)."""
    import ray
    if not ray.is_initialized():
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()
