"""Pure core of the Foxglove WebSocket bridge (no ROS import): schema texts, /clock decoding and
the checks a Foxglove service call goes through before it reaches ROS.

Schemas. Every channel of the bridge carries the schema the MCAP writer stores for its type
(:func:`biped_sim.recording.mcap_recorder.build_message_definition`: name ``pkg/msg/Type``, encoding
``ros2msg``, the ``.msg`` text followed by each dependency once, separated by a line of 80 ``=`` and
``MSG: pkg/Type``), so one Foxglove layout works live and on replay. A service (``pkg/srv/Type``,
file ``share/<pkg>/srv/<Type>.srv``) is split at its ``---`` line into a request and a response
part; each part is flattened the same way (:func:`flatten_definition`) and named
``pkg/srv/Type_Request`` / ``pkg/srv/Type_Response``, as rosidl names the generated messages.

Messages are passed through as CDR bytes (message encoding ``cdr``). A CDR payload starts with a
4-byte encapsulation header: a big-endian representation identifier (``0x0000`` CDR big endian,
``0x0001`` CDR little endian, what Fast DDS writes) and 2 option bytes; the body's alignment is
counted from the end of the header.

Times are integer nanoseconds of sim time (the simulator's ``/clock``).
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from biped_sim.recording.mcap_recorder import (
    SEPARATOR,
    RecorderError,
    _field_dependencies,
    _find_share_file,
)

SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'
SUBPROTOCOL = 'foxglove.sdk.v1'     # the only WebSocket subprotocol the foxglove-sdk server accepts

CDR_BE = 0x0000
CDR_LE = 0x0001
_BYTE_ORDER = {CDR_BE: '>', CDR_LE: '<'}
CDR_HEADER = 4                      # bytes of the encapsulation header

_SRV_NAME = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)/srv/([A-Za-z][A-Za-z0-9_]*)$')
_SPLIT_LINE = re.compile(r'^---[ \t]*$', re.MULTILINE)


class BridgeRequestError(ValueError):
    """A Foxglove client's service call that cannot be handed to ROS (wrong encoding, not CDR,
    undecodable); the call fails with this message and nothing reaches the graph."""


@dataclass(frozen=True)
class ServiceDefinition:
    """Schema texts of one ROS 2 service, ready for a Foxglove ``ServiceSchema``."""
    name: str               # 'pkg/srv/Type'
    request_name: str       # 'pkg/srv/Type_Request'
    request_text: str       # flattened ros2msg text of the request part
    response_name: str      # 'pkg/srv/Type_Response'
    response_text: str


def _read_msg(package: str, name: str, prefixes: Sequence[Path]) -> str:
    path = _find_share_file(package, name, '.msg', prefixes)
    if path is None:
        searched = ', '.join(str(p) for p in prefixes) or '(no prefixes)'
        raise RecorderError(f'message definition {package}/msg/{name}.msg not found under share/ of: {searched}')
    return path.read_text(encoding='utf-8')


def flatten_definition(text: str, package: str, prefixes: Sequence[Path]) -> str:
    """The ``ros2msg`` schema text of a message whose own definition is ``text`` (field types
    without a package are looked up in ``package``): ``text``, then every dependency once,
    depth-first, each file's dependencies in sorted order, each as ``\\n`` + 80 ``=`` + ``\\nMSG:
    pkg/Type\\n`` + its text. For the text of ``share/<pkg>/msg/<T>.msg`` this is exactly
    :func:`biped_sim.recording.mcap_recorder.build_message_definition` of ``pkg/msg/T`` (the same
    dependency parser; tested on every topic type). Raises RecorderError naming a missing file."""
    seen: set[str] = set()

    def append(body: str, pkg: str, depth: int) -> str:
        if depth > 50:
            raise RecorderError(f'message definition nesting too deep in package {pkg}')
        out = body
        for dep in _field_dependencies(body, pkg):
            if dep in seen:
                continue
            seen.add(dep)
            dep_pkg, dep_name = dep.split('/')
            out += f'\n{SEPARATOR}\nMSG: {dep}\n' + append(_read_msg(dep_pkg, dep_name, prefixes), dep_pkg, depth + 1)
        return out

    return append(text, package, 0)


def split_service_text(text: str) -> tuple[str, str]:
    """(request part, response part) of a ``.srv`` text: split at its one ``---`` line (the newline
    before it belongs to the request part, the one after it to neither). Raises BridgeRequestError
    when there is not exactly one such line."""
    parts = _SPLIT_LINE.split(text)
    if len(parts) != 2:
        raise BridgeRequestError(f'a .srv text has exactly one "---" line; found {len(parts) - 1}')
    request, response = parts
    if request.endswith('\n'):
        request = request[:-1]
    if response.startswith('\n'):
        response = response[1:]
    return request, response


def service_definition(type_name: str, prefixes: Sequence[Path]) -> ServiceDefinition:
    """Request and response schema texts of ``pkg/srv/Type`` from ``<prefix>/share/<pkg>/srv/<Type>.srv``
    (first prefix that has it). Raises RecorderError when the file (or a dependency) is missing,
    BridgeRequestError for a malformed name or file."""
    m = _SRV_NAME.match(type_name)
    if m is None:
        raise BridgeRequestError(f'not a service type name (pkg/srv/Type): {type_name!r}')
    pkg, name = m.groups()
    path = next((Path(p) / 'share' / pkg / 'srv' / f'{name}.srv' for p in prefixes
                 if (Path(p) / 'share' / pkg / 'srv' / f'{name}.srv').is_file()), None)
    if path is None:
        searched = ', '.join(str(p) for p in prefixes) or '(no prefixes)'
        raise RecorderError(f'service definition {pkg}/srv/{name}.srv not found under share/ of: {searched}')
    request, response = split_service_text(path.read_text(encoding='utf-8'))
    return ServiceDefinition(
        name=type_name,
        request_name=f'{type_name}_Request', request_text=flatten_definition(request, pkg, prefixes),
        response_name=f'{type_name}_Response', response_text=flatten_definition(response, pkg, prefixes))


def cdr_byte_order(payload: bytes) -> str:
    """``'<'`` (CDR little endian) or ``'>'`` (big endian) from the encapsulation header of a plain
    CDR payload. Raises BridgeRequestError for a payload shorter than the header or another
    representation (parameter lists, XCDR2)."""
    if len(payload) < CDR_HEADER:
        raise BridgeRequestError(f'a CDR payload starts with a {CDR_HEADER}-byte header; got {len(payload)} bytes')
    rep = int.from_bytes(payload[:2], 'big')
    if rep not in _BYTE_ORDER:
        raise BridgeRequestError(f'CDR representation 0x{rep:04x} is not plain CDR (0x0000 big endian, '
                                 f'0x0001 little endian)')
    return _BYTE_ORDER[rep]


def clock_ns(payload: bytes) -> int:
    """Sim time in ns from a CDR ``rosgraph_msgs/msg/Clock`` (``builtin_interfaces/Time clock``:
    int32 sec, uint32 nanosec, right after the header): sec * 1e9 + nanosec. Raises
    BridgeRequestError for a payload that is not one (wrong header or size, nanosec >= 1e9)."""
    order = cdr_byte_order(payload)
    if len(payload) < CDR_HEADER + 8:
        raise BridgeRequestError(f'a CDR Clock has {CDR_HEADER + 8} bytes; got {len(payload)}')
    sec, nanosec = struct.unpack_from(f'{order}iI', payload, CDR_HEADER)
    if nanosec >= 1_000_000_000:
        raise BridgeRequestError(f'Clock nanosec {nanosec} >= 1e9')
    return sec * 1_000_000_000 + nanosec


def check_call(encoding: str, payload: bytes, expected_encoding: str = MESSAGE_ENCODING) -> None:
    """A Foxglove service call's payload may be handed to the ROS deserializer: its encoding is
    ``expected_encoding`` (``cdr``) and it starts with a plain CDR header. Raises BridgeRequestError
    naming what is wrong; the ROS deserializer then rejects a body too short for the request type."""
    if encoding != expected_encoding:
        raise BridgeRequestError(f'request encoding {encoding!r} is not supported; use {expected_encoding!r}')
    cdr_byte_order(payload)
