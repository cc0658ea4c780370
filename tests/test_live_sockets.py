"""TCP_NODELAY on the Foxglove server's sockets (biped_sim.live.sockets).

The pure function against plain sockets (a listener's TCP_NODELAY is inherited by the sockets it accepts, the
duplicate descriptors leave the server's own ones open), then the bridge node in this process: after a WebSocket
handshake the server's accepted socket has TCP_NODELAY with ``tcp_nodelay`` true and not with false (the SDK's own
default: the negative control, which also shows the workaround is still needed)."""
from __future__ import annotations

import socket

import pytest

from biped_sim.live.sockets import nodelay_of_port, set_nodelay_on_port


def _nodelay(s: socket.socket) -> bool:
    return s.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0


def test_listener_and_accepted_sockets_get_nodelay_and_stay_open():
    listener = socket.create_server(('127.0.0.1', 0))
    port = listener.getsockname()[1]
    early = socket.create_connection(('127.0.0.1', port))
    early_server, _ = listener.accept()          # connected before the call: set directly
    other = socket.create_server(('127.0.0.1', 0))   # another port: untouched
    try:
        assert not _nodelay(listener) and not _nodelay(early_server)
        report = set_nodelay_on_port(port)
        assert (report.listening, report.connected, report.set) == (1, 1, 2)
        assert _nodelay(listener) and _nodelay(early_server)
        assert not _nodelay(other)
        assert not _nodelay(early)                  # the client's end (local port is not the server's)
        late = socket.create_connection(('127.0.0.1', port))
        late_server, _ = listener.accept()
        assert _nodelay(late_server)               # inherited from the listener
        assert sorted(nodelay_of_port(port)) == [(False, True), (False, True), (True, True)]
        # the server's descriptors are still open and working after the duplicates were closed
        late.sendall(b'ping')
        assert late_server.recv(4) == b'ping'
        late.close()
        late_server.close()
    finally:
        for s in (listener, early, early_server, other):
            s.close()


def test_a_port_without_sockets_and_bad_ports():
    probe = socket.create_server(('127.0.0.1', 0))
    port = probe.getsockname()[1]
    probe.close()
    assert set_nodelay_on_port(port) == type(set_nodelay_on_port(port))(0, 0, 0)
    assert nodelay_of_port(port) == []
    for bad in (0, -1, 65536):
        with pytest.raises(ValueError, match='port must be in 1..65535'):
            set_nodelay_on_port(bad)


@pytest.mark.ros
@pytest.mark.parametrize('flag', [True, False])
def test_bridge_server_sockets_have_nodelay_as_configured(rclpy_context, flag):
    import websockets.sync.client
    from rclpy.parameter import Parameter
    from biped_sim.live.bridge_node import BridgeNode

    node = BridgeNode(subscribe=False, context=rclpy_context, parameter_overrides=[
        Parameter('port', Parameter.Type.INTEGER, 0), Parameter('tcp_nodelay', Parameter.Type.BOOL, flag)])
    try:
        port = node.port
        assert nodelay_of_port(port) == [(True, flag)]
        # the handshake completes only after the server accepted the connection: its socket is in this process
        with websockets.sync.client.connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1'],
                                            open_timeout=60) as ws:
            states = nodelay_of_port(port)
            assert (True, flag) in states
            assert (False, flag) in states, states      # the accepted client socket inherited (or not) the flag
            assert ws.subprotocol == 'foxglove.sdk.v1'
    finally:
        node.server.stop()
        node.destroy_node()
