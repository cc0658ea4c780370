"""Read rosbag2 MCAP bags back (pure: no ROS import).

- :func:`read_bag` reads a finished bag (directory or ``.mcap`` file) through its summary.
- :func:`read_truncated` reads a file that lost its tail (recorder killed with SIGKILL, disk
  full): it keeps every complete record, so the messages of every complete chunk, and stops at
  the first incomplete one without raising.
- :func:`recover_bag` rewrites such a file into a finished, indexed bag (``scripts/bag recover IN OUT``,
  like the MCAP CLI's ``mcap recover``); ``python -m biped_sim.recording.bag_reader recover IN OUT``.

Both return plain dicts; times are nanoseconds (``log_time``).
"""

from __future__ import annotations

import dataclasses
import io
import os
import struct
import zlib
from pathlib import Path
from typing import Any, Dict, List, Optional

import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

__all__ = ["BagReadError", "RecoveryReport", "find_mcap", "read_bag", "read_truncated", "recover_bag",
           "complete_prefix_length"]

_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, length
_OPCODE_FOOTER = 0x02


class BagReadError(Exception):
    """The path holds no readable MCAP bag."""


def find_mcap(path: os.PathLike | str) -> Path:
    """The MCAP file of a bag: ``path`` itself, or the first file of the bag directory.

    In a directory, ``metadata.yaml``'s ``relative_file_paths`` wins over a glob.
    """
    path = Path(path)
    if path.is_file():
        return path
    if not path.is_dir():
        raise BagReadError(f"no such bag: {path}")
    meta = path / "metadata.yaml"
    if meta.is_file():
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        files = info.get("relative_file_paths") or []
        if files:
            return path / files[0]
    found = sorted(path.glob("*.mcap"))
    if not found:
        raise BagReadError(f"no .mcap file in {path}")
    return found[0]


def _decoder_factories(decode: bool) -> list:
    if not decode:
        return []
    from mcap_ros2.decoder import DecoderFactory  # imported lazily: only needed to decode
    return [DecoderFactory()]


def read_bag(path: os.PathLike | str, decode: bool = False) -> Dict[str, Any]:
    """Read a finished bag.

    :returns: ``{"path", "counts": {topic: n}, "types": {topic: pkg/msg/Type},
        "message_count", "start_ns", "end_ns", "compression": set of chunk compressions,
        "chunk_count", "has_summary", "metadata": parsed metadata.yaml or None,
        "messages": [(topic, log_time, publish_time, decoded)]}`` (``messages`` only with
        ``decode=True``; decoded with ``mcap_ros2.decoder``).
    """
    mcap_path = find_mcap(path)
    bag_dir = mcap_path.parent
    metadata = None
    if (bag_dir / "metadata.yaml").is_file():
        metadata = yaml.safe_load((bag_dir / "metadata.yaml").read_text(encoding="utf-8"))
    counts: Dict[str, int] = {}
    types: Dict[str, str] = {}
    start: Optional[int] = None
    end: Optional[int] = None
    messages: List[tuple] = []
    with open(mcap_path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=_decoder_factories(decode))
        summary = reader.get_summary()
        if summary is None:
            raise BagReadError(f"{mcap_path} has no summary (truncated? use read_truncated)")
        for channel in summary.channels.values():
            schema = summary.schemas.get(channel.schema_id)
            types[channel.topic] = schema.name if schema else ""
            counts.setdefault(channel.topic, 0)
        compression = {ci.compression for ci in summary.chunk_indexes}
        if decode:
            iterator = reader.iter_decoded_messages(log_time_order=True)
        else:
            iterator = ((s, c, m, None) for s, c, m in reader.iter_messages(log_time_order=True))
        for _schema, channel, message, decoded in iterator:
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            start = message.log_time if start is None else min(start, message.log_time)
            end = message.log_time if end is None else max(end, message.log_time)
            if decode:
                messages.append((channel.topic, message.log_time, message.publish_time, decoded))
    result = {
        **_summary_fields(mcap_path, counts, types, start, end),
        "compression": compression,
        "chunk_count": len(summary.chunk_indexes),
        "has_summary": True,
        "metadata": metadata,
    }
    if decode:
        result["messages"] = messages
    return result


def _summary_fields(path, counts: Dict[str, int], types, start, end) -> Dict[str, Any]:
    """The fields shared by read_bag and read_truncated."""
    return {"path": path, "counts": counts, "types": types, "message_count": sum(counts.values()),
            "start_ns": start, "end_ns": end}


def complete_prefix_length(data: bytes) -> int:
    """Length of the longest prefix of ``data`` made of the magic and whole records."""
    if not data.startswith(_MAGIC):
        return 0
    pos = len(_MAGIC)
    while pos + _RECORD_HEAD.size <= len(data):
        opcode, length = _RECORD_HEAD.unpack_from(data, pos)
        end = pos + _RECORD_HEAD.size + length
        if end > len(data):
            break
        pos = end
        if opcode == _OPCODE_FOOTER:
            break
    return pos


@dataclasses.dataclass
class _Scan:
    """What a scan of a (possibly truncated) MCAP file found, records in file order."""

    records: List[Any]          # Schema, Channel, Message, Metadata records, chunks opened, in order
    complete_chunks: int
    bad_chunks: int
    saw_header: bool
    saw_footer: bool


def _scan_truncated(data: bytes) -> _Scan:
    """The records of the longest complete prefix of ``data`` (chunks opened; a chunk whose CRC or
    decompression fails is counted as bad and skipped)."""
    prefix = complete_prefix_length(data)
    records: List[Any] = []
    complete_chunks = bad_chunks = 0
    saw_header = saw_footer = False
    if prefix > 0:
        reader = StreamReader(io.BytesIO(data[:prefix]), emit_chunks=True)
        try:
            for record in reader.records:
                if isinstance(record, Chunk):
                    inner = _chunk_records(record)
                    if inner is None:
                        bad_chunks += 1
                        continue
                    complete_chunks += 1
                    records.extend(inner)
                else:
                    if isinstance(record, Header):
                        saw_header = True
                    if isinstance(record, Footer):
                        saw_footer = True
                    records.append(record)
        except (McapError, struct.error, ValueError, EOFError):
            pass  # end of the complete prefix (EndOfFile) or a damaged record: stop there
    return _Scan(records, complete_chunks, bad_chunks, saw_header, saw_footer)


def read_truncated(path: os.PathLike | str, decode: bool = False) -> Dict[str, Any]:
    """Read the complete records of an MCAP file that may lack its summary and footer.

    The file is first cut at its last whole record; the mcap ``StreamReader`` then reads that
    prefix. Chunks whose CRC or decompression fails are counted in ``"bad_chunks"`` and skipped.
    A chunk that reached the disk whole therefore yields all its messages, and nothing raises on
    a cut anywhere (an empty dict of counts if not even the header survived).

    :returns: ``{"path", "counts", "types", "message_count", "start_ns", "end_ns",
        "complete_chunks", "bad_chunks", "truncated": bool, "messages": [...]}`` where messages
        are ``(topic, log_time, publish_time, data_or_decoded)``.
    """
    mcap_path = find_mcap(path)
    scan = _scan_truncated(mcap_path.read_bytes())
    counts: Dict[str, int] = {}
    types: Dict[str, str] = {}
    schemas: Dict[int, Schema] = {}
    channels: Dict[int, Channel] = {}
    messages: List[tuple] = []
    start: Optional[int] = None
    end: Optional[int] = None
    decoders: Dict[int, Any] = {}
    factories = _decoder_factories(decode)
    for record in scan.records:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
            schema = schemas.get(record.schema_id)
            types[record.topic] = schema.name if schema else ""
            counts.setdefault(record.topic, 0)
        elif isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is None:
                continue  # its channel was in a lost chunk: cannot attribute it
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            start = record.log_time if start is None else min(start, record.log_time)
            end = record.log_time if end is None else max(end, record.log_time)
            payload: Any = record.data
            if factories:
                decoder = decoders.get(channel.id)
                if decoder is None:
                    decoder = factories[0].decoder_for(channel.message_encoding,
                                                       schemas.get(channel.schema_id))
                    decoders[channel.id] = decoder
                payload = decoder(record.data) if decoder else None
            messages.append((channel.topic, record.log_time, record.publish_time, payload))
    return {
        **_summary_fields(mcap_path, counts, types, start, end),
        "complete_chunks": scan.complete_chunks,
        "bad_chunks": scan.bad_chunks,
        "truncated": not scan.saw_footer,
        "messages": messages,
    }


@dataclasses.dataclass(frozen=True)
class RecoveryReport:
    """What :func:`recover_bag` rewrote (times in nanoseconds, log time)."""

    source: Path                 # the MCAP file read
    bag_dir: Path                # the finished bag written
    mcap_path: Path
    message_count: int
    counts: Dict[str, int]
    complete_chunks: int         # chunks of the source read whole
    bad_chunks: int              # chunks of the source skipped (CRC or decompression failed)
    truncated: bool              # the source had no footer
    unattributed: int            # messages of the source whose channel record was lost (not copied)
    metadata_names: List[str]    # metadata records copied (the writer adds its own 'rosbag2')
    end_ns: Optional[int]        # last log time copied


def recover_bag(source: os.PathLike | str, out_dir: os.PathLike | str, *, compression: str = "auto",
                chunk_size: Optional[int] = None) -> RecoveryReport:
    """Rewrite the readable part of a bag (finished or truncated, e.g. a recorder killed with SIGKILL)
    into a new finished bag: a valid, indexed MCAP (summary, chunk and message indexes, statistics)
    plus ``metadata.yaml``, in the recorder's rosbag2 layout (``<out_dir>/<name>_0.mcap``).

    Copied, in the source's order: every schema, channel (its ``offered_qos_profiles`` and
    ``topic_type_hash``), message (log time, publish time, CDR bytes unchanged) of every complete chunk
    and every metadata record except ``rosbag2``, which is written anew from what was copied. The
    messages of the chunk being built when the recorder died are not in the file and cannot be copied.

    :param source: a bag directory or an ``.mcap`` file.
    :param out_dir: the new bag directory; must not exist or be empty (nothing is written otherwise).
    :raises BagReadError: no MCAP header in the source, or a schema that is not ``ros2msg`` / a channel
        that is not ``cdr`` (not a rosbag2 bag).
    :raises RecorderError: the output cannot be created or written.
    """
    from biped_sim.recording.mcap_recorder import DEFAULT_CHUNK_SIZE, Rosbag2McapWriter, qos_from_yaml

    mcap_path = find_mcap(source)
    scan = _scan_truncated(mcap_path.read_bytes())
    if not scan.saw_header:
        raise BagReadError(f"{mcap_path}: no MCAP header (not an MCAP file, or cut before its first record)")
    schemas: Dict[int, Schema] = {}
    channels: Dict[int, Channel] = {}
    for record in scan.records:   # check everything before the output is created
        if isinstance(record, Schema):
            if record.encoding != "ros2msg":
                raise BagReadError(f"{mcap_path}: schema {record.name!r} is {record.encoding!r}, not ros2msg")
        elif isinstance(record, Channel) and record.message_encoding != "cdr":
            raise BagReadError(f"{mcap_path}: channel {record.topic!r} is {record.message_encoding!r}, not cdr")
    unattributed = 0
    copied_metadata: List[str] = []
    end: Optional[int] = None
    with Rosbag2McapWriter(out_dir, prefixes=[], compression=compression,
                           chunk_size=chunk_size or DEFAULT_CHUNK_SIZE) as bag:
        for record in scan.records:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                schema = schemas.get(channel.schema_id) if channel is not None else None
                if schema is None:
                    unattributed += 1
                    continue
                if channel.topic not in bag.topics:
                    bag.register_topic(channel.topic, schema.name,
                                       qos_from_yaml(channel.metadata.get("offered_qos_profiles", "")),
                                       type_hash=channel.metadata.get("topic_type_hash", ""),
                                       definition=schema.data.decode("utf-8"))
                bag.write(channel.topic, schema.name, record.data, record.log_time, record.publish_time)
                end = record.log_time if end is None else max(end, record.log_time)
            elif isinstance(record, Metadata) and record.name != "rosbag2":
                bag.add_metadata(record.name, dict(record.metadata))
                copied_metadata.append(record.name)
    summary = bag.finish()
    return RecoveryReport(source=mcap_path, bag_dir=summary.bag_dir, mcap_path=summary.mcap_path,
                          message_count=summary.message_count, counts=dict(summary.counts),
                          complete_chunks=scan.complete_chunks, bad_chunks=scan.bad_chunks,
                          truncated=not scan.saw_footer, unattributed=unattributed,
                          metadata_names=copied_metadata, end_ns=end)


def _chunk_records(chunk: Chunk) -> Optional[List[Any]]:
    """The records inside a chunk, or None if it does not decompress or fails its CRC."""
    try:
        if chunk.compression == "":
            raw = chunk.data
        elif chunk.compression == "zstd":
            import zstandard
            try:
                raw = zstandard.ZstdDecompressor().decompress(
                    chunk.data, max_output_size=chunk.uncompressed_size)
            except zstandard.ZstdError:
                return None
        elif chunk.compression == "lz4":
            import lz4.frame
            raw = lz4.frame.decompress(chunk.data)  # raises RuntimeError on bad data
        else:
            return None
    except (RuntimeError, ValueError):
        return None
    if len(raw) != chunk.uncompressed_size:
        return None
    if chunk.uncompressed_crc and zlib.crc32(raw) != chunk.uncompressed_crc:
        return None
    try:
        return breakup_chunk(dataclasses.replace(chunk, compression="", data=raw))
    except (McapError, ValueError, struct.error, UnicodeDecodeError):
        return None


def main(argv: Optional[List[str]] = None) -> int:
    """``recover IN OUT``: rewrite a (truncated) bag into a finished one; prints what was kept. Exit 0 on
    success, 1 when the source cannot be read or the output cannot be written (nothing written then)."""
    import argparse
    import sys

    from biped_sim.recording.mcap_recorder import RecorderError

    ap = argparse.ArgumentParser(prog="bag", description="Tools for the recorder's bags.")
    sub = ap.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("recover", help="rewrite a truncated bag (recorder killed) into a finished, indexed bag")
    rec.add_argument("source", type=Path, help="bag directory or .mcap file")
    rec.add_argument("out", type=Path, help="new bag directory (must not exist, or be empty)")
    a = ap.parse_args(argv)
    try:
        r = recover_bag(a.source, a.out)
    except (BagReadError, RecorderError, OSError) as exc:
        print(f"bag recover: {exc}", file=sys.stderr)
        return 1
    span = "" if r.end_ns is None else f", last log time {r.end_ns * 1e-9:.3f} s"
    print(f"recovered {r.message_count} messages from {r.complete_chunks} complete chunks of {r.source}"
          f" ({r.bad_chunks} bad chunks, {r.unattributed} messages without a channel; "
          f"{'truncated' if r.truncated else 'finished'} source{span}) -> {r.mcap_path}")
    for topic, n in sorted(r.counts.items()):
        print(f"  {topic}: {n}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
