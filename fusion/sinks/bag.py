"""File sinks in ROS 2 formats: a rosbag2 folder and a single MCAP file (``ros`` extra).

The rosbag2 folder is always built aside and moved into place complete; the MCAP file can
also be recorded live, crash-safe (:class:`McapSink` ``live=True``).
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

from fusion.io.atomic import AtomicDirectory, AtomicFile
from fusion.io.incremental import DEFAULT_SYNC_INTERVAL, IncrementalFile
from fusion.sinks.base import Sink, _need
from fusion.sinks.cdr import _ros2_type, encode_cdr
from fusion.sinks.ros_messages import MESSAGE_TYPES, Topics, ros_messages, stamp_ns
from fusion.types.fused import FusedOdometry

__all__ = ["McapSink", "Rosbag2Sink"]


class Rosbag2Sink(Sink):
    """A rosbag2 recording (folder with ``metadata.yaml``) of the topics of :class:`Topics`.

    Written with the ``rosbags`` package in ROS 2 CDR encoding (Jazzy message definitions; the
    five message types are identical in every ROS 2 distribution) with bag metadata version 8,
    the oldest that ``rosbags`` writes (a ROS 2 release older than that metadata version may
    refuse ``metadata.yaml``; the MCAP data file inside is self-contained). The bag is built in a
    temporary folder next to ``path`` and renamed into place on close; an existing bag at
    ``path`` is a FileExistsError at ``open()`` unless ``overwrite=True``, and is replaced only
    by a complete one.

    Args:
        path: the bag folder to create.
        storage: ``"mcap"`` (default) or ``"sqlite3"``.
        topics: topic names (:class:`Topics`).
        overwrite: replace an existing bag at ``path``.
        compression: ``"zstd"`` compresses MCAP chunks (every MCAP reader, Foxglove and
            ``ros2 bag`` included, reads them; files several times smaller); None does not;
            ``"auto"`` (default) is zstd for MCAP, none for sqlite3.
    """

    def __init__(self, path: str | Path, *, storage: str = "mcap", topics: Topics | None = None,
                 overwrite: bool = False, compression: str | None = "auto") -> None:
        super().__init__()
        if storage not in ("mcap", "sqlite3"):
            raise ValueError(f"storage must be 'mcap' or 'sqlite3', got {storage!r}")
        if compression == "auto":
            compression = "zstd" if storage == "mcap" else None
        if compression not in (None, "zstd") or (compression and storage != "mcap"):
            raise ValueError(f"compression must be None or 'zstd' (MCAP storage only), got "
                             f"{compression!r} with {storage}")
        self.path = Path(path)
        self.storage = storage
        self.compression = compression
        self.topics = topics or Topics()
        self.overwrite = overwrite
        self._staged: AtomicDirectory | None = None
        self._writer: Any = None
        self._connections: dict[str, Any] = {}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r})"

    def _open(self) -> None:
        rosbag2 = _need("rosbags.rosbag2", "ros")
        typesys = _need("rosbags.typesys", "ros")
        self._ts = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
        self._staged = AtomicDirectory(self.path, overwrite=self.overwrite)
        plugin = {"mcap": rosbag2.StoragePlugin.MCAP,
                  "sqlite3": rosbag2.StoragePlugin.SQLITE3}[self.storage]
        try:
            self._writer = rosbag2.Writer(self._staged.staging / self.path.name, version=8,
                                          storage_plugin=plugin)
            if self.compression == "zstd":  # zstd-compressed MCAP chunks
                self._writer.set_compression(rosbag2.CompressionMode.STORAGE,
                                             rosbag2.CompressionFormat.ZSTD)
            self._writer.open()
            for key, topic in self.topics.as_dict().items():
                if topic is not None:
                    self._connections[key] = self._writer.add_connection(
                        topic, _ros2_type(MESSAGE_TYPES[key]), typestore=self._ts)
        except BaseException:
            self._discard()
            raise

    def _write(self, record: FusedOdometry) -> None:
        for key, _topic, msgtype, fields in ros_messages(record, self.topics):
            data = encode_cdr(msgtype, fields)
            self._writer.write(self._connections[key], stamp_ns(record.t), data)

    def _finish_writer(self) -> Path:
        assert self._writer is not None and self._staged is not None
        writer, self._writer = self._writer, None
        writer.close()
        return self._staged.staging / self.path.name

    def _close(self) -> None:
        try:
            built = self._finish_writer()
            assert self._staged is not None
            self._staged.commit(built)  # replacing an old bag if allowed
        except BaseException:
            self._discard()
            raise
        self._discard()

    def _discard(self) -> None:
        if self._writer is not None:
            writer, self._writer = self._writer, None
            with contextlib.suppress(Exception):
                writer.close()
        if self._staged is not None:
            self._staged.discard()
            self._staged = None

    def _abort(self) -> None:
        self._discard()


class McapSink(Sink):
    """One self-contained ``.mcap`` file (ROS 2 profile, CDR messages with their ``ros2msg``
    schemas, the Jazzy definitions of :class:`Rosbag2Sink`) that Foxglove and any MCAP reader
    open directly; written with the ``mcap`` package.

    Two modes:

    - offline (default): built in a hidden temporary file and renamed over ``path`` on close
      (:class:`fusion.io.atomic.AtomicFile`): an existing file is replaced only by a complete
      one; an error (``abort``) leaves it untouched. Equal records give byte-identical files.
    - ``live=True`` (``fusion run``): a recording that survives a crash. Every
      ``sync_interval`` seconds the open chunk is closed, written and fsynced
      (:class:`fusion.io.incremental.IncrementalFile`), so after a SIGKILL or a power loss the
      file at ``path`` holds every message up to the last sync; only its summary section (the
      index at the end) is missing. :func:`fusion.io.bags.read_bag` reads such a file (up to
      its last complete record), as does the ``mcap`` package's
      :class:`mcap.stream_reader.StreamReader` (until it raises ``EndOfFile``), and the
      ``mcap recover`` tool rewrites it into a complete file. A clean stop (close, and also
      abort once records were written) writes the summary.

    Args:
        path: the ``.mcap`` file to write.
        topics: topic names (:class:`Topics`).
        overwrite: replace an existing file at ``path`` (True by default, as for any single
            output file).
        compression: ``"zstd"`` (default) or None, per chunk.
        live: record live (crash-safe) instead of replacing the file atomically.
        sync_interval: with ``live``, seconds between syncs (> 0).
    """

    def __init__(self, path: str | Path, *, topics: Topics | None = None,
                 overwrite: bool = True, compression: str | None = "zstd", live: bool = False,
                 sync_interval: float = DEFAULT_SYNC_INTERVAL) -> None:
        super().__init__()
        if compression not in (None, "zstd"):
            raise ValueError(f"compression must be None or 'zstd', got {compression!r}")
        if not sync_interval > 0:
            raise ValueError(f"sync_interval must be > 0 s, got {sync_interval}")
        self.path = Path(path)
        self.topics = topics or Topics()
        self.overwrite = overwrite
        self.compression = compression
        self.live = live
        self.sync_interval = sync_interval
        self._out: AtomicFile | None = None
        self._writer: Any = None
        self._channels: dict[str, int] = {}

    def __repr__(self) -> str:
        return f"McapSink({str(self.path)!r})"

    def _open(self) -> None:
        mcap_writer = _need("mcap.writer", "ros")
        typesys = _need("rosbags.typesys", "ros")
        store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
        if self.live:
            self._out = IncrementalFile(self.path, "wb", overwrite=self.overwrite,
                                        sync_interval=self.sync_interval)
        else:
            self._out = AtomicFile(self.path, "wb", overwrite=self.overwrite)
        try:
            compression = (mcap_writer.CompressionType.ZSTD if self.compression == "zstd"
                           else mcap_writer.CompressionType.NONE)
            self._writer = mcap_writer.Writer(self._out.file, compression=compression)
            self._writer.start(profile="ros2", library="diffbot-fusion")
            schemas: dict[str, int] = {}
            for key, topic in self.topics.as_dict().items():
                if topic is None:
                    continue
                name = _ros2_type(MESSAGE_TYPES[key])
                if name not in schemas:
                    text = store.generate_msgdef(name, ros_version=2)[0]
                    schemas[name] = self._writer.register_schema(name, "ros2msg",
                                                                 text.encode())
                self._channels[key] = self._writer.register_channel(topic, "cdr",
                                                                    schemas[name])
        except BaseException:
            self._out.discard()
            raise

    def _write(self, record: FusedOdometry) -> None:
        ns = stamp_ns(record.t)
        for key, _topic, msgtype, fields in ros_messages(record, self.topics):
            self._writer.add_message(self._channels[key], log_time=ns, publish_time=ns,
                                     data=encode_cdr(msgtype, fields))
        if isinstance(self._out, IncrementalFile) and self._out.sync_interval_passed():
            self._writer.flush()  # close the open chunk: the file is readable up to here
            self._out.sync()

    def _close(self) -> None:
        assert self._out is not None
        try:
            self._writer.finish()
        except BaseException:
            self._out.discard()
            raise
        self._out.commit()

    def _abort(self) -> None:
        if self._out is None:
            return
        if self.live and self.records_written:  # a live recording keeps what it has
            self._close()
        else:
            self._out.discard()
