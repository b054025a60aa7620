"""``tf.train.Example`` records written for the tests, as TensorFlow serialises them (the package only reads them)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

_LENGTH = 2  # protobuf wire type of length-delimited fields


def _encode_varint(value: int) -> bytes:
    value &= (1 << 64) - 1
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _length_field(number: int, payload: bytes) -> bytes:
    return _encode_varint(number << 3 | _LENGTH) + _encode_varint(len(payload)) + payload


def serialize_example(features: Mapping[str, bytes | Sequence[bytes] | np.ndarray | Sequence[float]]) -> bytes:
    """Encode ``{name: bytes, list of bytes, float array or int array}`` as a ``tf.train.Example``."""
    entries = b""
    for key, value in features.items():
        if isinstance(value, bytes):
            value = [value]
        if isinstance(value, list) and all(isinstance(item, bytes) for item in value):
            feature = _length_field(1, b"".join(_length_field(1, item) for item in value))
        else:
            array = np.asarray(value)
            if np.issubdtype(array.dtype, np.integer):
                packed = b"".join(_encode_varint(int(item)) for item in array.ravel())
                feature = _length_field(3, _length_field(1, packed))
            else:
                feature = _length_field(2, _length_field(1, array.astype("<f4").ravel().tobytes()))
        entries += _length_field(1, _length_field(1, key.encode()) + _length_field(2, feature))
    return _length_field(1, entries)
