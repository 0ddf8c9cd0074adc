"""A parameter written in parts (XCP on CAN): what is held, completed, dropped or refused."""

from __future__ import annotations

import struct

import pytest

from controller.xcp_table import controller_layout
from service_kit.xcp.memory import WriteRefused
from service_kit.xcp.packets import Err
from service_kit.xcp.partial import PartialWrites

LAYOUT = controller_layout()
KP1, KP2, TICK = LAYOUT.by_name["kp1"], LAYOUT.by_name["kp2"], LAYOUT.by_name["tick"]


def test_first_bytes_held_then_completed() -> None:
    p = PartialWrites(LAYOUT)
    data = struct.pack("<d", 9.25)
    first = p.split(KP1.address, data[:6])
    assert (first.whole, first.held) == (b"", data[:6]) and p.variable == KP1
    done = p.split(KP1.address + 6, data[6:])
    assert (done.address, done.whole, done.held) == (KP1.address, data, b"")
    assert p.variable is None and p.dropped == 0
    assert LAYOUT.check_write(done.address, done.whole)[0].physical == 9250.0


def test_whole_parameters_taken_and_the_tail_held() -> None:
    p = PartialWrites(LAYOUT)
    data = struct.pack("<dd", 1.0, 2.0)
    out = p.split(KP1.address, data[:12])  # kp1 whole, kp2's first four bytes
    assert (out.address, out.whole, out.held) == (KP1.address, data[:8], data[8:12]) and p.variable == KP2
    out = p.split(KP2.address + 4, data[12:])
    assert (out.address, out.whole, out.held) == (KP2.address, data[8:], b"")


def test_a_write_elsewhere_drops_the_held_bytes() -> None:
    p = PartialWrites(LAYOUT)
    p.split(KP1.address, b"\0" * 6)
    out = p.split(KP2.address, struct.pack("<d", 3.0))
    assert (out.address, out.held) == (KP2.address, b"") and p.dropped == 1
    p.split(KP1.address, b"\0" * 6)
    p.drop()  # the session's end
    assert p.dropped == 2 and p.variable is None
    p.drop()  # nothing held: nothing counted
    assert p.dropped == 2


@pytest.mark.parametrize(
    ("address", "data", "code"),
    [
        (KP1.address + 2, b"\0" * 4, Err.ERR_ACCESS_DENIED),  # starts and ends inside: no first bytes
        (KP1.address + 6, b"\0\0", Err.ERR_ACCESS_DENIED),  # the last bytes with nothing held (checked whole)
        (TICK.address, b"\0\0", Err.ERR_WRITE_PROTECTED),  # a measurement's first bytes
        (LAYOUT.end, b"\0\0", Err.ERR_ACCESS_DENIED),  # outside the map
        (KP1.address, struct.pack("<d", -1.0) + b"\0\0", Err.ERR_OUT_OF_RANGE),  # a whole part out of range: nothing held
    ],
)
def test_refused(address: int, data: bytes, code: Err) -> None:
    p = PartialWrites(LAYOUT)
    with pytest.raises(WriteRefused) as info:
        out = p.split(address, data)
        LAYOUT.check_write(out.address, out.whole)  # what the slave does with the whole part
    assert info.value.code == code and p.variable is None
