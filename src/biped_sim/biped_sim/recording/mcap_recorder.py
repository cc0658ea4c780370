"""rosbag2-compatible MCAP bag writer (pure core: no ROS import).

A bag is a directory ``<bag_dir>/`` holding ``<name>_0.mcap`` (``name`` = the directory's base
name, as rosbag2 names its files) and ``metadata.yaml`` in the rosbag2 Jazzy format (version 9).

MCAP conventions followed (rosbag2_storage_mcap, Jazzy):
- header profile ``ros2``;
- one schema per message type, named ``pkg/msg/Type``, encoding ``ros2msg``, whose data is the
  ``.msg`` text followed, for every dependency (depth-first, each once, dependencies of one file in
  sorted order), by a newline, a line of 80 ``=``, ``MSG: pkg/Type`` and that file's text;
- channels with message encoding ``cdr`` and metadata ``offered_qos_profiles`` (a YAML string:
  the list of offered profiles) and ``topic_type_hash`` (``RIHS01_...``, empty when unknown);
- chunked, compressed, indexed (chunk indexes, message indexes, statistics, summary offsets);
- a metadata record named ``rosbag2`` whose ``serialized_metadata`` is the text of metadata.yaml.

Times are nanosecond integers: ``log_time`` = receive time (sim time when recording with sim
time), ``publish_time`` = source time.

Messages arrive already CDR-serialized (raw pass-through); nothing here decodes them.

Durability. A chunk is written out when it holds ``chunk_size`` bytes of uncompressed records *or*
(``chunk_time``) when its first message was added ``chunk_time`` seconds ago (monotonic wall clock;
checked at every message and by :meth:`Rosbag2McapWriter.poll`, which the recorder node calls from a
timer so a quiet graph's last messages are closed too). The file is written unbuffered, so a written
chunk is in the kernel's page cache at once:

- a crash of the process (SIGKILL) loses the chunk being built (at most ``chunk_time`` s of messages, or
  ``chunk_size`` bytes) and the summary; every written chunk reads back
  (:func:`biped_sim.recording.bag_reader.read_truncated`) and
  :func:`biped_sim.recording.bag_reader.recover_bag` rewrites the file into a finished, indexed bag;
- a power cut (or kernel crash) also loses what the kernel had not written back yet: with ``sync`` off,
  up to the kernel's dirty-page expiry (Linux ``vm.dirty_expire_centisecs``, 30 s by default) on top;
  with ``sync`` on, every chunk is ``fdatasync``-ed when written, so the bound stays one chunk (the
  cost of a sync per chunk is measured by ``lab/benchmarks/recorder_durability.py``).
"""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import re
import time
from pathlib import Path
from typing import Any, Dict, Iterable, List, Optional, Sequence, Tuple

import yaml
from mcap.writer import CompressionType, IndexType, Writer

from biped_model.finite import finite_number

try:  # optional compressors; the choice is reported by Rosbag2McapWriter.compression
    import zstandard as _zstandard
except ImportError:  # pragma: no cover - depends on the environment
    _zstandard = None
try:
    import lz4.frame as _lz4_frame
except ImportError:  # pragma: no cover - depends on the environment
    _lz4_frame = None

try:
    from mcap import __version__ as _MCAP_VERSION
except ImportError:  # pragma: no cover
    _MCAP_VERSION = "unknown"

__all__ = [
    "RecorderError",
    "QosProfile",
    "TopicInfo",
    "BagSummary",
    "Rosbag2McapWriter",
    "build_message_definition",
    "find_type_hash",
    "normalize_type_name",
    "prefixes_from_env",
    "available_compression",
    "qos_from_yaml",
    "METADATA_VERSION",
    "DEFAULT_CHUNK_SIZE",
]

METADATA_VERSION = 9  # rosbag2 Jazzy
ROS_DISTRO = "jazzy"
DEFAULT_CHUNK_SIZE = 256 * 1024  # bytes of uncompressed records per chunk
LIBRARY = f"biped_sim.recording.mcap_recorder; mcap-python/{_MCAP_VERSION}"
SEPARATOR = "=" * 80

# rmw's RMW_DURATION_INFINITE, as rmw implementations report it for "no deadline" etc.
INFINITE_DURATION: Tuple[int, int] = (9223372036, 854775807)

_PRIMITIVES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
})
_NAME = r"[A-Za-z][A-Za-z0-9_]*"
_TYPE_NAME_RE = re.compile(rf"^({_NAME})/(?:msg/)?({_NAME})$")


class RecorderError(Exception):
    """A bag cannot be created or written; the message says which file and why."""


# --------------------------------------------------------------------------------------------
# QoS
# --------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class QosProfile:
    """An offered QoS profile, in the vocabulary of rosbag2 metadata version 9.

    Durations are ``(sec, nsec)``; ``INFINITE_DURATION`` is what rmw reports for "none".
    """

    history: str = "keep_last"          # keep_last | keep_all | system_default | unknown
    depth: int = 10
    reliability: str = "reliable"       # reliable | best_effort | system_default | unknown
    durability: str = "volatile"        # volatile | transient_local | system_default | unknown
    deadline: Tuple[int, int] = INFINITE_DURATION
    lifespan: Tuple[int, int] = INFINITE_DURATION
    liveliness: str = "automatic"       # automatic | manual_by_topic | system_default | unknown
    liveliness_lease_duration: Tuple[int, int] = INFINITE_DURATION
    avoid_ros_namespace_conventions: bool = False

    def to_yaml_dict(self) -> Dict[str, Any]:
        def dur(value: Tuple[int, int]) -> Dict[str, int]:
            return {"sec": int(value[0]), "nsec": int(value[1])}

        return {
            "history": self.history,
            "depth": int(self.depth),
            "reliability": self.reliability,
            "durability": self.durability,
            "deadline": dur(self.deadline),
            "lifespan": dur(self.lifespan),
            "liveliness": self.liveliness,
            "liveliness_lease_duration": dur(self.liveliness_lease_duration),
            "avoid_ros_namespace_conventions": bool(self.avoid_ros_namespace_conventions),
        }


def _qos_yaml(profiles: Sequence[QosProfile]) -> str:
    """The YAML text of a list of profiles (the MCAP channel's ``offered_qos_profiles``)."""
    return yaml.safe_dump([p.to_yaml_dict() for p in profiles], sort_keys=False,
                          default_flow_style=False)


# --------------------------------------------------------------------------------------------
# Message definitions
# --------------------------------------------------------------------------------------------

def normalize_type_name(type_name: str) -> Tuple[str, str]:
    """``pkg/msg/Type`` or ``pkg/Type`` -> ``(pkg, Type)``; raises RecorderError otherwise."""
    match = _TYPE_NAME_RE.match(type_name)
    if match is None:
        raise RecorderError(f"not a message type name (pkg/msg/Type): {type_name!r}")
    return match.group(1), match.group(2)


def prefixes_from_env(env: Optional[Dict[str, str]] = None) -> List[Path]:
    """Install prefixes from ``AMENT_PREFIX_PATH`` (colon-separated, first wins)."""
    env = os.environ if env is None else env
    return [Path(p) for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]


def _find_share_file(pkg: str, name: str, suffix: str, prefixes: Sequence[Path]) -> Optional[Path]:
    for prefix in prefixes:
        candidate = Path(prefix) / "share" / pkg / "msg" / f"{name}{suffix}"
        if candidate.is_file():
            return candidate
    return None


def _field_dependencies(text: str, package: str) -> List[str]:
    """Non-primitive field types of one .msg text, as sorted unique ``pkg/Type`` names.

    Handles comments, constants (``uint8 A=1``: always primitive), arrays (``T[]``, ``T[17]``,
    ``T[<=5]``) and bounded strings (``string<=10``).
    """
    deps = set()
    for raw_line in text.splitlines():
        line = raw_line.split("#", 1)[0].strip()
        if not line:
            continue
        field_type = line.split()[0]
        field_type = field_type.split("[", 1)[0]
        base = re.split(r"<=", field_type, maxsplit=1)[0]
        if base in _PRIMITIVES:
            continue
        if "/" in base:
            pkg, name = normalize_type_name(base)
        else:
            if not re.fullmatch(_NAME, base):
                raise RecorderError(f"cannot parse field type {base!r} in package {package}")
            pkg, name = package, base
        deps.add(f"{pkg}/{name}")
    return sorted(deps)


def build_message_definition(type_name: str, prefixes: Sequence[Path]) -> str:
    """The full ``ros2msg`` schema text of ``type_name`` (see module docstring).

    Files are read from ``<prefix>/share/<pkg>/msg/<Type>.msg`` (first prefix that has it).
    Raises RecorderError naming the missing file.
    """
    seen: set = set()

    def load(pkg: str, name: str) -> str:
        path = _find_share_file(pkg, name, ".msg", prefixes)
        if path is None:
            searched = ", ".join(str(p) for p in prefixes) or "(no prefixes)"
            raise RecorderError(
                f"message definition {pkg}/msg/{name}.msg not found under share/ of: {searched}")
        return path.read_text(encoding="utf-8")

    def append(pkg: str, name: str, depth: int) -> str:
        if depth > 50:
            raise RecorderError(f"message definition nesting too deep at {pkg}/{name}")
        text = load(pkg, name)
        out = text
        for dep in _field_dependencies(text, pkg):
            if dep in seen:
                continue
            seen.add(dep)
            dep_pkg, dep_name = dep.split("/")
            out += f"\n{SEPARATOR}\nMSG: {dep}\n" + append(dep_pkg, dep_name, depth + 1)
        return out

    pkg, name = normalize_type_name(type_name)
    return append(pkg, name, 0)


def find_type_hash(type_name: str, prefixes: Sequence[Path]) -> str:
    """``RIHS01_...`` from ``share/<pkg>/msg/<Type>.json`` (rosidl's type description), or ''."""
    pkg, name = normalize_type_name(type_name)
    path = _find_share_file(pkg, name, ".json", prefixes)
    if path is None:
        return ""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return ""
    full = f"{pkg}/msg/{name}"
    for entry in data.get("type_hashes", []):
        if entry.get("type_name") == full:
            return str(entry.get("hash_string", ""))
    return ""


# --------------------------------------------------------------------------------------------
# Writer
# --------------------------------------------------------------------------------------------

def available_compression() -> str:
    """Best available chunk compression: 'zstd', else 'lz4', else 'none'."""
    if _zstandard is not None:
        return "zstd"
    if _lz4_frame is not None:
        return "lz4"
    return "none"


_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}


@dataclasses.dataclass
class TopicInfo:
    """One recorded topic: its channel and what metadata.yaml says about it."""

    name: str
    type_name: str                      # pkg/msg/Type
    qos_profiles: Tuple[QosProfile, ...]
    type_hash: str
    channel_id: int
    message_count: int = 0


@dataclasses.dataclass(frozen=True)
class BagSummary:
    """What a finished bag holds (all times in nanoseconds)."""

    bag_dir: Path
    mcap_path: Path
    counts: Dict[str, int]
    message_count: int
    start_ns: int
    end_ns: int
    compression: str
    complete: bool                      # False if an I/O error cut the recording short


def qos_from_yaml(text: str) -> Tuple["QosProfile", ...]:
    """The profiles of an MCAP channel's ``offered_qos_profiles`` YAML text (as :func:`_qos_yaml` writes it;
    unknown keys are ignored, missing ones take :class:`QosProfile`'s field defaults).

    :raises RecorderError: when the text is not a YAML list of mappings."""
    try:
        items = yaml.safe_load(text) if text else []
    except yaml.YAMLError as exc:
        raise RecorderError(f"offered_qos_profiles is not YAML: {exc}") from exc
    if items is None:
        items = []
    if not isinstance(items, list) or not all(isinstance(i, dict) for i in items):
        raise RecorderError(f"offered_qos_profiles is not a list of profiles: {text!r}")
    fields = {f.name for f in dataclasses.fields(QosProfile)}
    out = []
    for item in items:
        kwargs: Dict[str, Any] = {}
        for key, value in item.items():
            if key not in fields:
                continue
            if isinstance(value, dict) and set(value) == {"sec", "nsec"}:
                value = (int(value["sec"]), int(value["nsec"]))
            kwargs[key] = value
        out.append(QosProfile(**kwargs))
    return tuple(out)


class _UnbufferedSink:
    """Write-through file sink: what the mcap Writer hands over reaches the OS at once.

    (mcap's Writer would wrap a raw file into a BufferedWriter; this object is not a RawIOBase,
    so it is used as is.)  Chunks are large, so writing them unbuffered costs nothing, and a
    SIGKILL then loses only the chunk being built.
    """

    def __init__(self, fd: int) -> None:
        self._file = os.fdopen(fd, "wb", buffering=0)
        self._pos = 0

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            written = self._file.write(view)
            if written is None or written == 0:
                raise OSError(errno.EIO, "short write")
            view = view[written:]
            self._pos += written
        return len(data)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass

    def sync(self) -> None:
        """``fdatasync``: what was written is on the storage device (survives a power cut)."""
        os.fdatasync(self._file.fileno())

    def close(self) -> None:
        try:
            os.fsync(self._file.fileno())
        finally:
            self._file.close()


class Rosbag2McapWriter:
    """Writes one rosbag2 bag directory with a single MCAP file.

    Use as a context manager (``finish()`` then runs exactly once, even on error)::

        with Rosbag2McapWriter("runs/bag1", prefixes=prefixes_from_env()) as bag:
            bag.write("/chatter", "std_msgs/msg/String", cdr, log_time_ns, publish_time_ns)

    :param bag_dir: bag directory; created (with parents). It must not exist or be empty.
    :param prefixes: install prefixes whose ``share/<pkg>/msg`` hold the ``.msg`` files.
    :param compression: 'zstd' | 'lz4' | 'none' | 'auto' (best available, see
        :func:`available_compression`).
    :param chunk_size: uncompressed bytes per chunk before it is written out.
    :param chunk_time: seconds (monotonic wall clock) after a chunk's first message at which the chunk is
        written out even if not full (checked at each message and by :meth:`poll`); None = by size only.
    :param sync: ``fdatasync`` the file after each chunk written (a power cut then loses at most the
        chunk being built; see the module docstring).
    :param clock: monotonic time source [s] for ``chunk_time`` (tests pass their own).
    :raises RecorderError: at construction, before anything is written, if the directory
        cannot be created or written, already holds files, or the compression is unavailable.
    """

    def __init__(self, bag_dir: os.PathLike | str, *, prefixes: Sequence[os.PathLike | str],
                 compression: str = "auto", chunk_size: int = DEFAULT_CHUNK_SIZE,
                 chunk_time: Optional[float] = None, sync: bool = False,
                 clock=time.monotonic, ros_distro: str = ROS_DISTRO) -> None:
        self._finished = False
        self._summary: Optional[BagSummary] = None
        self._sink: Optional[_UnbufferedSink] = None
        self._writer: Optional[Writer] = None
        self._io_error: Optional[BaseException] = None

        if compression == "auto":
            compression = available_compression()
        if compression not in _COMPRESSION:
            raise RecorderError(
                f"compression must be one of zstd, lz4, none, auto; got {compression!r}")
        if compression == "zstd" and _zstandard is None:
            raise RecorderError("compression 'zstd' requested but the zstandard module is missing")
        if compression == "lz4" and _lz4_frame is None:
            raise RecorderError("compression 'lz4' requested but the lz4 module is missing")
        if not isinstance(chunk_size, int) or isinstance(chunk_size, bool) or chunk_size < 1:
            raise RecorderError(f"chunk_size must be a positive integer; got {chunk_size!r}")
        if chunk_time is not None:
            finite_number(chunk_time, "chunk_time", above=0, error=RecorderError,
                          message=f"chunk_time must be a finite number of seconds > 0 (or None); got {chunk_time!r}")
        if not isinstance(sync, bool):
            raise RecorderError(f"sync must be a bool; got {sync!r}")
        self.chunk_time = None if chunk_time is None else float(chunk_time)
        self.sync = sync
        self._clock = clock
        self._chunk_opened: Optional[float] = None   # clock() at the first message of the open chunk
        self.chunks_written = 0                      # chunks (and data records) handed to the file
        self.syncs = 0

        self.compression = compression
        self.chunk_size = chunk_size
        self.ros_distro = ros_distro
        self.prefixes = [Path(p) for p in prefixes]
        self.bag_dir = Path(bag_dir).absolute()
        name = self.bag_dir.name
        if not name:
            raise RecorderError(f"bag directory has no name: {str(bag_dir)!r}")
        self.mcap_name = f"{name}_0.mcap"
        self.mcap_path = self.bag_dir / self.mcap_name
        self.metadata_path = self.bag_dir / "metadata.yaml"

        self._topics: Dict[str, TopicInfo] = {}
        self._schemas: Dict[str, int] = {}
        self._start_ns: Optional[int] = None
        self._end_ns: Optional[int] = None
        self._count = 0

        created = self._create_dir()
        try:
            flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
            fd = os.open(self.mcap_path, flags, 0o644)
        except OSError as exc:
            self._remove_created(created)
            raise RecorderError(f"cannot create {self.mcap_path}: {exc.strerror or exc}") from exc
        self._sink = _UnbufferedSink(fd)
        try:
            self._writer = Writer(self._sink, chunk_size=chunk_size,
                                  compression=_COMPRESSION[compression],
                                  index_types=IndexType.ALL, use_chunking=True,
                                  use_statistics=True, use_summary_offsets=True)
            self._writer.start(profile="ros2", library=LIBRARY)
        except OSError as exc:
            self._sink.close()
            self.mcap_path.unlink(missing_ok=True)
            self._remove_created(created)
            raise RecorderError(f"cannot write {self.mcap_path}: {exc.strerror or exc}") from exc

    # -- construction helpers ------------------------------------------------------------------

    def _create_dir(self) -> List[Path]:
        """Create the bag directory (and missing parents); return what was created, deepest last."""
        if self.bag_dir.exists():
            if not self.bag_dir.is_dir():
                raise RecorderError(f"bag path exists and is not a directory: {self.bag_dir}")
            if any(self.bag_dir.iterdir()):
                raise RecorderError(
                    "bag directory already exists and is not empty (existing bag?): "
                    f"{self.bag_dir}")
            if not os.access(self.bag_dir, os.W_OK | os.X_OK):
                raise RecorderError(f"bag directory is not writable: {self.bag_dir}")
            return []
        missing: List[Path] = []
        probe = self.bag_dir
        while not probe.exists():
            missing.append(probe)
            if probe.parent == probe:
                break
            probe = probe.parent
        if not probe.is_dir():
            raise RecorderError(
                f"cannot create bag directory {self.bag_dir}: {probe} is not a directory")
        if not os.access(probe, os.W_OK | os.X_OK):
            raise RecorderError(
                f"cannot create bag directory {self.bag_dir}: {probe} is not writable")
        created: List[Path] = []
        for path in reversed(missing):
            try:
                path.mkdir()
            except OSError as exc:
                self._remove_created(created)
                raise RecorderError(
                    f"cannot create bag directory {self.bag_dir}: {exc.strerror or exc}") from exc
            created.append(path)
        return created

    @staticmethod
    def _remove_created(created: List[Path]) -> None:
        for path in reversed(created):
            try:
                path.rmdir()
            except OSError:
                pass  # best effort: leave a non-empty or vanished directory alone

    # -- context manager -----------------------------------------------------------------------

    def __enter__(self) -> "Rosbag2McapWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc is None:
            self.finish()
            return
        try:
            self.finish()
        except RecorderError as finish_exc:
            exc.add_note(f"and finishing the bag failed too: {finish_exc}")

    # -- recording -----------------------------------------------------------------------------

    @property
    def counts(self) -> Dict[str, int]:
        """Messages written so far, per topic."""
        return {name: t.message_count for name, t in self._topics.items()}

    @property
    def topics(self) -> Dict[str, TopicInfo]:
        return dict(self._topics)

    def has_topic(self, topic: str) -> bool:
        """Whether ``topic`` is registered (without copying :attr:`topics`)."""
        return topic in self._topics

    @property
    def finished(self) -> bool:
        return self._finished

    def register_topic(self, topic: str, type_name: str,
                       qos_profiles: Optional[Iterable[QosProfile]] = None,
                       type_hash: Optional[str] = None, definition: Optional[str] = None) -> TopicInfo:
        """Register a topic's channel (and its type's schema) if not yet done.

        :param qos_profiles: profiles offered by the topic's publishers (default: one default
            profile, reliable + volatile, depth 10).
        :param type_hash: RIHS01 hash; by default read from the type's ``.json`` file.
        :param definition: the schema's ``ros2msg`` text; by default built from the ``.msg`` files
            (:func:`build_message_definition`). Given when copying a bag (its own schema is kept); the
            first topic of a type decides its schema.
        :raises RecorderError: if the topic exists with another type, or the type's definition
            cannot be found.
        """
        self._check_open()
        pkg, name = normalize_type_name(type_name)
        full_type = f"{pkg}/msg/{name}"
        existing = self._topics.get(topic)
        if existing is not None:
            if existing.type_name != full_type:
                raise RecorderError(
                    f"topic {topic} is recorded as {existing.type_name}, not {full_type}")
            return existing
        if not topic.startswith("/"):
            raise RecorderError(f"topic name must be absolute: {topic!r}")
        profiles = tuple(qos_profiles) if qos_profiles is not None else (QosProfile(),)
        if type_hash is None:
            type_hash = find_type_hash(full_type, self.prefixes)
        schema_id = self._schemas.get(full_type)
        try:
            if schema_id is None:
                if definition is None:
                    definition = build_message_definition(full_type, self.prefixes)
                schema_id = self._writer.register_schema(
                    name=full_type, encoding="ros2msg", data=definition.encode("utf-8"))
                self._schemas[full_type] = schema_id
            channel_id = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema_id,
                metadata={"offered_qos_profiles": _qos_yaml(profiles),
                          "topic_type_hash": type_hash})
        except OSError as exc:
            self._fail(exc)
        info = TopicInfo(name=topic, type_name=full_type, qos_profiles=profiles,
                         type_hash=type_hash, channel_id=channel_id)
        self._topics[topic] = info
        return info

    def write(self, topic: str, type_name: str, data: bytes, log_time_ns: int,
              publish_time_ns: int) -> None:
        """Append one CDR-serialized message (raw pass-through).

        :param log_time_ns: receive time [ns] (sim time when recording with sim time).
        :param publish_time_ns: source time [ns].
        :raises RecorderError: on unknown type, on I/O error (after finishing what can be
            finished) or if the bag is already finished.
        """
        info = self._topics.get(topic)
        if info is None:
            info = self.register_topic(topic, type_name)
        else:
            self._check_open()
            if type_name != info.type_name:   # the recorded pkg/msg/Type as given: no parsing per message
                pkg, name = normalize_type_name(type_name)
                if info.type_name != f"{pkg}/msg/{name}":
                    raise RecorderError(
                        f"topic {topic} is recorded as {info.type_name}, not {type_name}")
        log_time_ns = int(log_time_ns)
        publish_time_ns = int(publish_time_ns)
        if log_time_ns < 0 or publish_time_ns < 0:
            raise RecorderError(f"negative timestamp on {topic}: {log_time_ns}, {publish_time_ns}")
        try:
            before = self._sink.tell()
            self._writer.add_message(channel_id=info.channel_id, log_time=log_time_ns,
                                     data=bytes(data), publish_time=publish_time_ns,
                                     sequence=info.message_count)
            if self._sink.tell() != before:   # the size limit closed the chunk (this message inside)
                self._after_chunk()
            elif self._chunk_opened is None:
                self._chunk_opened = self._clock()
            self.poll()
        except OSError as exc:
            self._fail(exc)
        info.message_count += 1
        self._count += 1
        self._start_ns = log_time_ns if self._start_ns is None else min(self._start_ns, log_time_ns)
        self._end_ns = log_time_ns if self._end_ns is None else max(self._end_ns, log_time_ns)

    def poll(self) -> bool:
        """Write the open chunk out if its first message is ``chunk_time`` s old (no-op without
        ``chunk_time``, on an empty chunk, or on a finished bag). Returns whether a chunk was written.

        :raises RecorderError: on an I/O error (after finishing what can be finished)."""
        if (self.chunk_time is None or self._finished or self._chunk_opened is None
                or self._clock() - self._chunk_opened < self.chunk_time):
            return False
        self.close_chunk()
        return True

    def close_chunk(self) -> None:
        """Write the chunk being built out now (compressed, with its message indexes), and sync it when
        ``sync``. No-op on an empty chunk.

        :raises RecorderError: on an I/O error (after finishing what can be finished) or a finished bag."""
        self._check_open()
        if self._chunk_opened is None:
            return
        try:
            self._writer.flush()   # mcap: finishes the chunk in progress and writes it to the sink
            self._after_chunk()
        except OSError as exc:
            self._fail(exc)

    def _after_chunk(self) -> None:
        self._chunk_opened = None
        self.chunks_written += 1
        if self.sync:
            self._sink.sync()
            self.syncs += 1

    def add_metadata(self, name: str, data: Dict[str, str]) -> None:
        """Write an MCAP metadata record ``name`` (string keys and values) now, in the data section (it is
        indexed in the summary at ``finish``, and a truncated file keeps it). Used for the plant's true
        parameters of a perturbed run (``biped_plant``), beside the latched ``/sim/plant`` topic.

        :raises RecorderError: on a non-string key or value, an I/O error, or a finished bag."""
        self._check_open()
        if name == "rosbag2" or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
            raise RecorderError(f"metadata {name!r}: a name other than 'rosbag2' and string keys and values")
        try:
            self._writer.add_metadata(name, dict(data))
        except OSError as exc:
            self._fail(exc)

    # -- finishing -----------------------------------------------------------------------------

    def metadata_dict(self) -> Dict[str, Any]:
        """metadata.yaml content (rosbag2 Jazzy, version 9) for what was written so far."""
        start = self._start_ns or 0
        duration = (self._end_ns - self._start_ns) if self._count else 0
        topics = []
        for info in self._topics.values():
            topics.append({
                "topic_metadata": {
                    "name": info.name,
                    "type": info.type_name,
                    "serialization_format": "cdr",
                    # Version 9 stores the offered profiles as a YAML sequence (earlier versions:
                    # a string holding YAML); the MCAP channel metadata keeps the string form.
                    "offered_qos_profiles": [p.to_yaml_dict() for p in info.qos_profiles],
                    "type_description_hash": info.type_hash,
                },
                "message_count": info.message_count,
            })
        return {"rosbag2_bagfile_information": {
            "version": METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": self._count,
            "topics_with_message_count": topics,
            # Chunk compression is internal to the MCAP storage; rosbag2 reports it as none.
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.mcap_name],
            "files": [{
                "path": self.mcap_name,
                "starting_time": {"nanoseconds_since_epoch": start},
                "duration": {"nanoseconds": duration},
                "message_count": self._count,
            }],
            "custom_data": None,
            "ros_distro": self.ros_distro,
        }}

    def metadata_yaml(self) -> str:
        return yaml.safe_dump(self.metadata_dict(), sort_keys=False, default_flow_style=False)

    def finish(self) -> BagSummary:
        """Close the bag: rosbag2 metadata record, summary/footer, metadata.yaml. Runs once.

        Later calls return the same summary.  If an I/O error stops it, it still closes the
        file and tries to write metadata.yaml, then raises RecorderError.
        """
        if self._finished:
            return self._summary
        self._finished = True
        errors: List[str] = []
        first_exc: Optional[BaseException] = None
        text = self.metadata_yaml()
        writer_ok = self._io_error is None
        if writer_ok:
            try:
                self._writer.add_metadata("rosbag2", {"serialized_metadata": text,
                                                      "ROS_DISTRO": self.ros_distro})
                self._writer.finish()
            except OSError as exc:
                writer_ok = False
                first_exc = exc
                errors.append(f"finishing {self.mcap_path}: {exc.strerror or exc}")
        if self._sink is not None:
            try:
                self._sink.close()
            except OSError as exc:
                first_exc = first_exc or exc
                errors.append(f"closing {self.mcap_path}: {exc.strerror or exc}")
        try:
            tmp = self.metadata_path.with_suffix(".yaml.tmp")
            tmp.write_text(text, encoding="utf-8")
            os.replace(tmp, self.metadata_path)
        except OSError as exc:
            first_exc = first_exc or exc
            errors.append(f"writing {self.metadata_path}: {exc.strerror or exc}")
        self._summary = BagSummary(
            bag_dir=self.bag_dir, mcap_path=self.mcap_path, counts=self.counts,
            message_count=self._count, start_ns=self._start_ns or 0, end_ns=self._end_ns or 0,
            compression=self.compression,
            complete=writer_ok and not errors and self._io_error is None)
        if errors:
            raise RecorderError("; ".join(errors)) from first_exc
        return self._summary

    def _check_open(self) -> None:
        if self._finished:
            raise RecorderError(f"bag {self.bag_dir} is already finished")

    def _fail(self, exc: OSError) -> None:
        """An I/O error while writing: finish what can be finished, then raise RecorderError."""
        self._io_error = exc
        notes = ""
        try:
            self.finish()
        except RecorderError as finish_exc:
            notes = f" (then: {finish_exc})"
        raise RecorderError(
            f"writing {self.mcap_path} failed: {exc.strerror or exc}{notes}; "
            f"{self._count} messages are in complete chunks or lost with the last chunk") from exc
