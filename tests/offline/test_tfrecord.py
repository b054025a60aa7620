"""The TFRecord container and the tf.train.Example codec, without TensorFlow."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from sb3_ef.offline.tfrecord import (
    CRC32C_IMPLEMENTATION,
    crc32c,
    masked_crc32c,
    parse_example,
    python_crc32c,
    read_records,
    write_records,
)
from tests.offline.examples import serialize_example


@pytest.mark.parametrize("implementation", [crc32c, python_crc32c])
def test_crc32c_matches_the_standard_check_value(implementation):
    assert implementation(b"123456789") == 0xE3069283  # the CRC-32C check value of RFC 3720
    assert implementation(b"") == 0


def test_c_crc32c_is_used_when_installed_and_equals_the_python_one():
    pytest.importorskip("google_crc32c")
    assert CRC32C_IMPLEMENTATION in ("google-crc32c", "crc32c")
    rng = np.random.default_rng(0)
    for size in (1, 7, 64, 1000, 65537):
        data = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
        assert crc32c(data) == python_crc32c(data)


def test_records_round_trip_with_checksums(tmp_path):
    path = tmp_path / "a.tfrecord"
    records = [b"", b"hello", bytes(range(256)) * 3]
    write_records(path, records)
    assert list(read_records(path)) == records
    raw = path.read_bytes()
    (length,) = struct.unpack("<Q", raw[:8])
    assert length == 0 and struct.unpack("<I", raw[8:12])[0] == masked_crc32c(raw[:8])


def test_corrupt_and_truncated_files_are_reported(tmp_path):
    path = tmp_path / "a.tfrecord"
    write_records(path, [b"hello world"])
    raw = bytearray(path.read_bytes())
    raw[14] ^= 0xFF
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"record 0 \(byte 0\) has a wrong CRC"):
        list(read_records(path))
    path.write_bytes(bytes(raw[:-6]))
    with pytest.raises(ValueError, match="record 0 is truncated"):
        list(read_records(path))


def test_example_round_trip_keeps_every_feature_kind():
    features = {
        "0/image_aux1/encoded": [b"\x00\x01\xff" * 10],
        "0/action": np.array([0.5, -1.25, 3.0, 0.0], dtype=np.float32),
        "steps": np.array([0, 1, -7, 2**40], dtype=np.int64),
        "names": [b"a", b"bc"],
    }
    decoded = parse_example(serialize_example(features))
    assert decoded.keys() == features.keys()
    assert decoded["0/image_aux1/encoded"] == features["0/image_aux1/encoded"]
    assert decoded["names"] == [b"a", b"bc"]
    np.testing.assert_array_equal(decoded["0/action"], features["0/action"])
    np.testing.assert_array_equal(decoded["steps"], features["steps"])
    assert decoded["0/action"].dtype == np.float32 and decoded["steps"].dtype == np.int64


def test_unpacked_float_lists_are_decoded_too():
    # FloatList with two unpacked fixed32 values (wire type 5), as older writers emit them.
    values = b"".join(b"\x0d" + struct.pack("<f", v) for v in (1.5, -2.0))
    feature = b"\x12" + bytes([len(values)]) + values
    entry = b"\x0a\x01x" + b"\x12" + bytes([len(feature)]) + feature
    features = b"\x0a" + bytes([len(entry)]) + entry
    example = b"\x0a" + bytes([len(features)]) + features
    np.testing.assert_array_equal(parse_example(example)["x"], [1.5, -2.0])


def test_a_flipped_length_field_is_called_corrupt_not_truncated(tmp_path):
    path = tmp_path / "a.tfrecord"
    write_records(path, [b"hello world", b"second"])
    raw = bytearray(path.read_bytes())
    raw[5] ^= 0x01  # a high bit of the first record's length: it now claims terabytes
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"record 0 \(byte 0\) has a corrupt length field .*: the file is damaged"):
        list(read_records(path))
    raw[5] ^= 0x01
    raw[0] ^= 0x01  # 10 instead of 11 bytes: the next record would start inside this one
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"record 0 \(byte 0\) has a corrupt length field"):
        list(read_records(path))
