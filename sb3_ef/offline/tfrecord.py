"""TFRecord files and ``tf.train.Example`` records without TensorFlow, and :class:`ExampleShards` of episodes."""

from __future__ import annotations

import os
import struct
import warnings
from collections.abc import Callable, Iterator, Sequence
from typing import BinaryIO

import numpy as np

from sb3_ef.common.files import write_atomically
from sb3_ef.offline.dataset import EpisodeDataset
from sb3_ef.offline.episodes import EpisodeError

_CRC_TABLE: list[int] = []
for _byte in range(256):
    _crc = _byte
    for _ in range(8):
        _crc = (_crc >> 1) ^ 0x82F63B78 if _crc & 1 else _crc >> 1
    _CRC_TABLE.append(_crc)

#: A decoded Example: feature name -> list of bytes, float32 array or int64 array.
Features = dict[str, "list[bytes] | np.ndarray"]


def python_crc32c(data: bytes) -> int:
    """CRC-32C of ``data`` in pure Python: the fallback when no C implementation is installed."""
    crc = 0xFFFFFFFF
    table = _CRC_TABLE
    for byte in data:
        crc = table[(crc ^ byte) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


def _fastest_crc32c() -> tuple[Callable[[bytes], int], str]:
    """The fastest installed CRC-32C and its name: ``google-crc32c``'s C build, ``crc32c``, else Python's."""
    try:
        import google_crc32c

        if google_crc32c.implementation == "c":
            return google_crc32c.value, "google-crc32c"
    except ImportError:
        pass
    try:
        import crc32c as crc32c_module

        return crc32c_module.crc32c, "crc32c"
    except ImportError:
        return python_crc32c, "python"


crc32c, CRC32C_IMPLEMENTATION = _fastest_crc32c()


def masked_crc32c(data: bytes) -> int:
    """The masked CRC TFRecord stores: rotate right by 15 bits and add a constant."""
    crc = crc32c(data)
    return (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF


def read_records(path: str | os.PathLike, check_crc: bool = True) -> Iterator[bytes]:
    """Yield the data of every record of a TFRecord file; a truncated file or a wrong checksum raises ``ValueError``."""
    with open(path, "rb") as file:
        for index, offset in enumerate(record_offsets(path)):
            yield read_record_at(file, offset, os.fspath(path), check_crc, index)


def record_offsets(path: str | os.PathLike) -> list[int]:
    """Byte offsets of every record from the length fields alone, each checked against its CRC (``ValueError``)."""
    offsets: list[int] = []
    size = os.path.getsize(path)
    with open(path, "rb") as file:
        position = 0
        while position < size:
            header = file.read(12)
            if len(header) < 12:
                raise ValueError(
                    f"{os.fspath(path)}: record {len(offsets)} is truncated (header of {len(header)} of 12 bytes)"
                )
            if struct.unpack("<I", header[8:])[0] != masked_crc32c(header[:8]):
                raise ValueError(
                    f"{os.fspath(path)}: record {len(offsets)} (byte {position}) has a corrupt length field (it does "
                    "not match its CRC-32C): the file is damaged"
                )
            (length,) = struct.unpack("<Q", header[:8])
            offsets.append(position)
            position += 12 + length + 4
            if position > size:
                raise ValueError(
                    f"{os.fspath(path)}: record {len(offsets) - 1} is truncated (expected {length} data bytes, "
                    f"the file ends {position - size} bytes early)"
                )
            file.seek(position)
    return offsets


def read_record_at(
    file: BinaryIO, offset: int, path: str = "", check_crc: bool = True, index: int | None = None
) -> bytes:
    """The data of the record at byte ``offset`` of an open TFRecord file, its two CRCs checked when ``check_crc``."""
    record = f"record {index} (byte {offset})" if index is not None else f"the record at byte {offset}"
    file.seek(offset)
    header = file.read(12)
    length = struct.unpack("<Q", header[:8])[0] if len(header) == 12 else 0
    data = file.read(length)
    footer = file.read(4)
    if len(header) < 12 or len(data) < length or len(footer) < 4:
        raise ValueError(f"{path}: {record} is truncated (expected {length} data bytes)")
    if check_crc and (
        struct.unpack("<I", header[8:])[0] != masked_crc32c(header[:8])
        or struct.unpack("<I", footer)[0] != masked_crc32c(data)
    ):
        raise ValueError(f"{path}: {record} has a wrong CRC-32C (corrupt file?)")
    return data


def write_records(path: str | os.PathLike, records: Sequence[bytes]) -> None:
    """Write ``records`` (serialised data) as a TFRecord file, whole or not at all (:mod:`sb3_ef.common.files`)."""

    def write(file: BinaryIO) -> None:
        for data in records:
            header = struct.pack("<Q", len(data))
            file.write(header + struct.pack("<I", masked_crc32c(header)))
            file.write(data + struct.pack("<I", masked_crc32c(data)))

    write_atomically(path, write)


# Protobuf wire format: tag = field number << 3 | wire type.
_VARINT, _FIXED64, _LENGTH, _FIXED32 = 0, 1, 2, 5


def _varint(buffer: bytes, position: int) -> tuple[int, int]:
    result, shift = 0, 0
    while True:
        byte = buffer[position]
        position += 1
        result |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return result, position
        shift += 7


def _fields(buffer: bytes) -> Iterator[tuple[int, int, bytes | int]]:
    """Yield ``(field number, wire type, value)``: bytes for length-delimited fields, ints otherwise."""
    position = 0
    while position < len(buffer):
        tag, position = _varint(buffer, position)
        number, wire = tag >> 3, tag & 7
        value: bytes | int
        if wire == _VARINT:
            value, position = _varint(buffer, position)
        elif wire == _LENGTH:
            length, position = _varint(buffer, position)
            if position + length > len(buffer):
                raise ValueError(f"field {number} needs {length} bytes, {len(buffer) - position} are left")
            value = buffer[position : position + length]
            position += length
        elif wire == _FIXED32:
            value = struct.unpack_from("<I", buffer, position)[0]
            position += 4
        elif wire == _FIXED64:
            value = struct.unpack_from("<Q", buffer, position)[0]
            position += 8
        else:
            raise ValueError(f"Unsupported protobuf wire type {wire} (field {number})")
        yield number, wire, value


def _length_delimited(value: bytes | int) -> bytes:
    """The bytes of a field that must be length-delimited (a message, string or bytes field)."""
    if not isinstance(value, bytes):
        raise TypeError(f"expected a length-delimited field, got the number {value}")
    return value


def _decode_feature(buffer: bytes) -> list[bytes] | np.ndarray:
    """A ``Feature``: field 1 BytesList, 2 FloatList, 3 Int64List; each list's values are its field 1."""
    for kind, _, field in _fields(buffer):
        payload = _length_delimited(field)
        if kind == 1:
            return [_length_delimited(value) for _, _, value in _fields(payload)]
        if kind == 2:
            floats = bytearray()
            for _, _, value in _fields(payload):
                floats += value if isinstance(value, bytes) else struct.pack("<I", value)  # packed or one fixed32
            return np.frombuffer(bytes(floats), dtype="<f4").astype(np.float32)
        if kind == 3:
            ints: list[int] = []
            for _, _, value in _fields(payload):
                if isinstance(value, bytes):  # packed
                    position = 0
                    while position < len(value):
                        number, position = _varint(value, position)
                        ints.append(number)
                else:
                    ints.append(value)
            return np.array([n - (1 << 64) if n >= 1 << 63 else n for n in ints], dtype=np.int64)
    return []


def parse_example(data: bytes) -> Features:
    """A serialised ``tf.train.Example`` as ``{name: list of bytes | float32 array | int64 array}``."""
    try:
        return _parse_example(data)
    except (IndexError, TypeError, ValueError, struct.error, UnicodeDecodeError) as error:
        raise ValueError(f"not a valid tf.train.Example ({type(error).__name__}: {error})") from error


def _parse_example(data: bytes) -> Features:
    features: Features = {}
    for number, _, features_message in _fields(data):
        if number != 1:
            continue
        for entry_number, _, entry in _fields(_length_delimited(features_message)):
            if entry_number != 1:
                continue
            key, value = "", b""
            for field, _, payload in _fields(_length_delimited(entry)):
                if field == 1:
                    key = _length_delimited(payload).decode()
                elif field == 2:
                    value = _length_delimited(payload)
            features[key] = _decode_feature(value)
    return features


class ExampleShards(EpisodeDataset):
    """Episodes stored one ``tf.train.Example`` per record of TFRecord shards (BAIR's, RLDS's), indexed on open."""

    def __init__(self, paths: Sequence[str], verify: bool = True, min_frames: int = 2):
        super().__init__(min_frames)
        self.paths, self.verify, self._records, empty = list(paths), verify, [], []
        for path in self.paths:
            try:
                offsets = record_offsets(path)
            except ValueError as error:
                raise EpisodeError(str(error)) from error
            empty += [] if offsets else [path]
            self._records += [(path, offset) for offset in offsets]
        if not self._records:
            raise EpisodeError(
                f"No records in {self.paths}: {len(empty)} of {len(self.paths)} TFRecord files are empty (0 bytes: an "
                "unfinished download or copy?)"
            )
        if empty:
            warnings.warn(f"Empty TFRecord files (0 bytes, no episode) skipped: {empty}", stacklevel=3)

    def __len__(self) -> int:
        return len(self._records)

    def _example(self, index: int) -> tuple[Features, str]:
        """The Example of episode ``index`` (its CRCs checked when ``verify``) and its source, for errors."""
        path, offset = self._records[index]
        source = f"{path} (episode {index})"
        with open(path, "rb") as file:
            try:
                return parse_example(read_record_at(file, offset, path, self.verify)), source
            except ValueError as error:
                raise EpisodeError(f"{source}: {error}") from error
