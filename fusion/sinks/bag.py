"""File sinks in ROS 2 formats: a rosbag2 folder and a single MCAP file (``ros`` extra).
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

from fusion.io.atomic import AtomicDirectory
from fusion.sinks.base import Sink, SinkError, _need
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
            self._writer = rosbag2.Writer(self._staged.staging / self._bag_name(), version=8,
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
        return self._staged.staging / self._bag_name()

    def _bag_name(self) -> str:
        return self.path.name

    def _close(self) -> None:
        try:
            built = self._finish_writer()
            self._install(built)
        except BaseException:
            self._discard()
            raise
        self._discard()

    def _install(self, built: Path) -> None:
        """Move the finished bag folder to ``path`` (replacing an old one if allowed)."""
        assert self._staged is not None
        self._staged.commit(built)

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


class McapSink(Rosbag2Sink):
    """One self-contained ``.mcap`` file (ROS 2 profile, CDR messages with their ``ros2msg``
    schemas) that Foxglove and any MCAP reader open directly.

    It is the data file of a :class:`Rosbag2Sink` bag with MCAP storage, moved to ``path`` by an
    atomic rename on close: an existing file at ``path`` is replaced only by a complete one
    (``overwrite`` defaults to True here, as for any single output file).
    """

    def __init__(self, path: str | Path, *, topics: Topics | None = None,
                 overwrite: bool = True, compression: str | None = "zstd") -> None:
        super().__init__(path, storage="mcap", topics=topics, overwrite=overwrite,
                         compression=compression)

    def _bag_name(self) -> str:
        # rosbags names the data file "<bag>.mcap" and records that name inside the file:
        # a bag named after the stem makes it the final name (and the bytes independent of
        # the temporary folder, so equal records give byte-identical files)
        return self.path.stem if self.path.suffix == ".mcap" else self.path.name

    def _install(self, built: Path) -> None:
        files = sorted(built.glob("*.mcap"))
        if len(files) != 1:
            raise SinkError(f"{self.path}: expected one MCAP file in the bag, found {files}")
        super()._install(files[0])  # a folder at path is an IsADirectoryError
