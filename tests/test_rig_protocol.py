"""The rig's line protocol (docs/rig-protocol.md): round trips, corruption, truncation, version.

Expected values come from the protocol's definition (a CRC-32 of the payload, zlib's), not
from the code's output.
"""

from __future__ import annotations

import zlib

import pytest

from phoid.rig.protocol import (
    ProtocolError,
    check_hello,
    encode,
    encode_config,
    hello,
    parse,
)


def test_a_line_is_payload_space_star_crc32():
    line = encode("START")
    assert line == b"START *682d973f\n"  # the example of docs/rig-protocol.md
    assert line == b"START *" + f"{zlib.crc32(b'START'):08x}".encode() + b"\n"
    assert hello() == b"PHOID-RIG 1 *" + f"{zlib.crc32(b'PHOID-RIG 1'):08x}".encode() + b"\n"


@pytest.mark.parametrize("kind, values", [
    ("SAMPLE", (12, 0.06, 0.0031234567891234567, -1.5e-7, "run")),
    ("SAMPLE", (12, 0.06, 0.0031234567891234567, -1.5e-7, "run", -0.3141592653589793)),
    ("EVENT", (405, "fault-growth", 0.0251)),
    ("END", ("done",)),
    ("ABORT", (3.0,)),
    ("OK", ()),
    ("CLEAR", ()),
])
def test_round_trips_keep_every_bit(kind, values):
    msg = parse(encode(kind, *values))
    assert msg.kind == kind
    assert tuple(msg.fields.values()) == values


def test_error_and_config_round_trip():
    assert parse(encode("ERROR", "sample_time  too\tshort")).fields == {
        "message": "sample_time too short"}
    cfg = {"sample_time": 0.005, "P": 66.7418810606096, "D": -35.0, "delay_samples": 1,
           "hold_samples": 400, "run_samples": 800, "x_start": 0.01, "velocity": 0}
    msg = parse(encode_config(cfg))
    assert msg.kind == "CONFIG" and msg.fields == cfg
    assert all(type(msg.fields[k]) is int for k in ("delay_samples", "hold_samples"))


def test_hello_and_version_mismatch():
    check_hello(parse(hello()), "the rig")
    with pytest.raises(ProtocolError, match="version 2; this phoid speaks PHOID-RIG 1 only"):
        check_hello(parse(hello(2)), "the rig")
    with pytest.raises(ProtocolError, match="did not say hello"):
        check_hello(parse(encode("OK")), "the rig")
    with pytest.raises(ProtocolError, match="refused the connection: busy"):
        check_hello(parse(encode("ERROR", "busy")), "the rig")


def test_corrupted_and_truncated_lines_are_detected():
    line = encode("SAMPLE", 7, 0.035, 0.0042, 1.25, "hold")
    flipped = line.replace(b"0.0042", b"0.0043")
    with pytest.raises(ProtocolError, match="checksum mismatch"):
        parse(flipped)
    with pytest.raises(ProtocolError, match="truncated line"):
        parse(line[:-1])
    with pytest.raises(ProtocolError, match="without its checksum"):
        parse(line[:15] + b"\n")
    # every single-byte corruption of the payload is caught (CRC-32 detects all of them)
    for i in range(len(line) - 11):
        bad = bytearray(line)
        bad[i] ^= 0x01
        with pytest.raises(ProtocolError):
            parse(bytes(bad))


def _framed(payload: bytes) -> bytes:
    return payload + b" *" + f"{zlib.crc32(payload):08x}".encode() + b"\n"


@pytest.mark.parametrize("payload, match", [
    (b"SAMPLE 1 0.1 0.2 0.3", "SAMPLE has 5 or 6 fields"),
    (b"SAMPLE 1 0.1 0.2 0.3 run 0.4 0.5", "SAMPLE has 5 or 6 fields"),
    (b"SAMPLE 1 0.1 0.2 0.3 run inf", "field `force` must be finite"),
    (b"SAMPLE 1 0.1 0.2 0.3 run N/A", "field `force` must be a number"),
    (b"SAMPLE 1 0.1 nan 0.3 run", "field `x` must be finite"),
    (b"SAMPLE 1.5 0.1 0.2 0.3 run", "field `index` must be a whole number"),
    (b"SAMPLE 1 0.1 0.2 0.3 flying", "field `state` must be one of"),
    (b"EVENT 3 release abc", "field `value` must be a number"),
    (b"CONFIG P=1 P=2", "field `P` given twice"),
    (b"CONFIG Q=1", "unknown field `Q`"),
    (b"CONFIG hold_samples=2.5", "field `hold_samples` must be a whole number"),
    (b"CONFIG P", "expected key=value"),
    (b"JUMP 3", "unknown message 'JUMP'"),
    (b"PHOID-RIG one", "hello must be"),
])
def test_bad_fields_are_named(payload, match):
    with pytest.raises(ProtocolError, match=match):
        parse(_framed(payload))


def test_a_sample_line_of_a_rig_without_a_force_sensor_parses_as_before():
    # an old-format line, framed by hand (docs/rig-protocol.md): five fields, no `force` key
    msg = parse(_framed(b"SAMPLE 3 0.015 0.0042 -1.25 run"))
    assert msg.kind == "SAMPLE"
    assert msg.fields == {"index": 3, "t": 0.015, "x": 0.0042, "u": -1.25, "state": "run"}
    # the same sample with the optional measured force: one more field, the rest unchanged
    msg = parse(_framed(b"SAMPLE 3 0.015 0.0042 -1.25 run -1.2625"))
    assert msg.fields == {"index": 3, "t": 0.015, "x": 0.0042, "u": -1.25, "state": "run",
                          "force": -1.2625}
    # encoding without a force writes the old five-field line, byte for byte
    assert encode("SAMPLE", 3, 0.015, 0.0042, -1.25, "run") == _framed(
        b"SAMPLE 3 0.015 0.0042 -1.25 run")


def test_encoding_refuses_what_cannot_be_sent():
    with pytest.raises(ProtocolError, match="field `x` must be a finite number"):
        encode("SAMPLE", 1, 0.0, float("inf"), 0.0, "run")
    with pytest.raises(ProtocolError, match="field `force` must be a finite number"):
        encode("SAMPLE", 1, 0.0, 0.0, 0.0, "run", float("nan"))
    with pytest.raises(ProtocolError, match="SAMPLE takes 5 or 6 fields"):
        encode("SAMPLE", 1, 0.0, 0.0, 0.0)
    with pytest.raises(ProtocolError, match="CONFIG field `run_samples` must be a whole"):
        encode_config({"run_samples": 2.5})
    with pytest.raises(ProtocolError, match="unknown field `Kp`"):
        encode_config({"Kp": 1.0})
    with pytest.raises(ProtocolError, match="one word"):
        encode("END", "two words")
