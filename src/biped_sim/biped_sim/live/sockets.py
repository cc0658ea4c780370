"""TCP_NODELAY on the Foxglove server's sockets, from outside the SDK (pure: no ROS).

Why. foxglove-sdk's WebSocket server (Rust, tokio; 0.30.3 and its main branch as read on 2026-11-25) never sets
``TCP_NODELAY`` on the sockets it accepts, so Nagle's algorithm is on: a small frame written while an earlier one
is not yet acknowledged waits in the kernel until that acknowledgement comes or a full segment (~64 KiB on the
loopback) is queued. A client that only reads (Foxglove, the benchmark's client) acknowledges with Linux's
delayed ACK, up to 40 ms later. Result at real time (``benchmarks/bridge_bench``): stalls of
~40-50 ms every few hundred milliseconds on the WebSocket path, each holding back 20-40 frames, while the frames
had left the recorder's thread within ~1 ms (traced per message: take -> client p99 33.6 ms, DDS -> take p99
13.5 ms).

How. On Linux a socket returned by ``accept()`` inherits ``TCP_NODELAY`` from the listening socket, so setting
it once on the server's listening socket(s) right after the server started covers every client that connects
later. The SDK gives no handle on its sockets; they are this process's own file descriptors, found by scanning
``/proc/self/fd``: every TCP socket whose local port is the server's (listening, or already connected to a
client) gets ``TCP_NODELAY`` = 1 through a duplicate of its descriptor (a socket option belongs to the socket,
not to the descriptor, so the duplicate sets it for the server's own descriptor; the duplicate is then closed).
"""
from __future__ import annotations

import os
import socket
from dataclasses import dataclass


@dataclass(frozen=True)
class NodelayReport:
    """What :func:`set_nodelay_on_port` found: descriptors of TCP sockets on the port, listening and connected,
    and how many of them now have ``TCP_NODELAY`` set."""
    listening: int
    connected: int
    set: int


def _tcp_sockets_on_port(port: int):
    """(duplicate socket object, listening?) for every TCP socket of this process whose local port is ``port``.
    The caller closes the duplicates."""
    try:
        names = os.listdir('/proc/self/fd')
    except OSError:
        return
    for name in names:
        try:
            dup = os.dup(int(name))
        except (OSError, ValueError):
            continue            # closed meanwhile (the listing's own descriptor among them)
        try:
            s = socket.socket(fileno=dup)
        except OSError:         # not a socket
            os.close(dup)
            continue
        try:
            ok = (s.family in (socket.AF_INET, socket.AF_INET6) and s.type == socket.SOCK_STREAM
                  and s.getsockname()[1] == port)
            listening = ok and bool(s.getsockopt(socket.SOL_SOCKET, socket.SO_ACCEPTCONN))
        except OSError:
            ok = False
        if ok:
            yield s, listening
        else:
            s.close()


def set_nodelay_on_port(port: int) -> NodelayReport:
    """Set ``TCP_NODELAY`` on every TCP socket of this process bound to local ``port`` (module docstring).

    :param port: the server's port (1..65535).
    :raises ValueError: ``port`` out of range.
    """
    if not 0 < int(port) < 65536:
        raise ValueError(f'port must be in 1..65535, got {port}')
    listening = connected = done = 0
    for s, is_listening in _tcp_sockets_on_port(int(port)):
        try:
            listening += is_listening
            connected += not is_listening
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            done += s.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0
        except OSError:
            pass
        finally:
            s.close()
    return NodelayReport(listening, connected, done)


def nodelay_of_port(port: int) -> list[tuple[bool, bool]]:
    """(listening?, TCP_NODELAY set?) of every TCP socket of this process on local ``port`` (for tests and logs)."""
    out = []
    for s, is_listening in _tcp_sockets_on_port(int(port)):
        try:
            out.append((is_listening, s.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0))
        finally:
            s.close()
    return out
