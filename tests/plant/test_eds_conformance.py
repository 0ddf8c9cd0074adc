"""The shipped EDS by the book, checked with tools nobody here wrote: Lely's
``dcfchk`` (``dcf-tools``, CiA 306) accepts it, the ``canopen`` package reads
it, INI readers find no ``=`` inside a value, REAL32 defaults are IEEE-754 bit
patterns, and what CiA 306 has no key for (units, scale factors,
descriptions, where ``rww`` objects refuse writes) is in comments, ObjFlags
and the units file, which the project reads back."""

from __future__ import annotations

import configparser
import json
import struct
import subprocess
import sys
from pathlib import Path

import canopen
import pytest

from plant_emulator.canopen_node import CanopenNode, NodeConfig, SdoAbortCode
from plant_emulator.canopen_node.eds import UNITS_FILE, apply_units, load_units, render_eds
from plant_emulator.canopen_node.objects import object_table
from plant_emulator.canopen_node.od import Access, DataType
from protocol.can_map import OD_ANALOG_INPUT_16, OD_ANALOG_OUTPUT_16, OD_VALVE_LIMIT, WORD16_VOLTS_PER_LSB, NmtCommand, encode_nmt
from tests.plant.support import EDS, FakeApp

UNITS = EDS.with_name(UNITS_FILE)


def dcfchk(path: Path) -> subprocess.CompletedProcess[str]:
    """Lely's checker as its console script runs it (``dcfchk -n 1 PATH``), from the test extra."""
    return subprocess.run([sys.executable, "-m", "dcf.cli", "-n", "1", str(path)], capture_output=True, text=True, timeout=60)


def test_dcfchk_accepts_the_shipped_eds() -> None:
    run = dcfchk(EDS)
    assert run.returncode == 0 and run.stderr == "", run.stderr[-2000:]


def test_dcfchk_refuses_what_the_eds_used_to_hold(tmp_path: Path) -> None:
    """The checker is not a rubber stamp: the keys and the decimal REAL32 the EDS used to carry fail it."""
    old = render_eds().replace("DefaultValue=0x41200000", "DefaultValue=10.0").replace("[2002]\n", "[2002]\nUnit=V\n")
    path = tmp_path / "old.eds"
    path.write_text(old)
    run = dcfchk(path)
    assert run.returncode == 1
    assert "invalid entry in [2002]: Unit" in run.stderr


def _eds() -> configparser.RawConfigParser:
    cp = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    cp.optionxform = str  # type: ignore[assignment,method-assign]
    cp.read(EDS)
    return cp


def test_no_value_holds_an_equals_sign_or_a_semicolon() -> None:
    """``eds-validate``-style readers split a line at every ``=`` and cut it at ``;``."""
    for line in EDS.read_text().splitlines():
        if not line or line.startswith(("[", ";")):
            assert "=" not in line or line.startswith("["), line
            continue
        key, value = line.split("=", 1)
        assert "=" not in value and ";" not in value, line


def test_real32_defaults_are_ieee754_bit_patterns() -> None:
    cp = _eds()
    real32 = [(o, e) for o in object_table() for e in o.entries if e.dtype is DataType.REAL32]
    assert real32  # 0x2002 at least
    for o, e in real32:
        section = f"{e.index:04X}" if len(o.entries) == 1 else f"{e.index:04X}sub{e.sub:X}"
        raw = cp[section]["DefaultValue"]
        assert raw.startswith("0x") and len(raw) == 10
        assert struct.unpack(">f", int(raw, 16).to_bytes(4, "big"))[0] == e.default
    assert cp[f"{OD_VALVE_LIMIT:04X}"]["DefaultValue"] == "0x41200000"  # 10.0 V


def test_the_units_file_holds_what_cia306_has_no_key_for_and_canopen_reads_it() -> None:
    units = load_units(UNITS)
    assert units == load_units()  # the packaged copy is the shipped file
    expected = {(e.index, e.sub): e for o in object_table() for e in o.entries if e.unit or e.factor is not None or e.description}
    assert set(units) == set(expected)
    for key, e in expected.items():
        assert (units[key].unit, units[key].factor, units[key].description) == (e.unit, e.factor, e.description)
    od = canopen.import_od(str(EDS), 1)
    assert od.get_variable(OD_ANALOG_INPUT_16, 1).factor == 1  # the EDS alone: no scale (no non-standard key)
    assert apply_units(od) == len(units)
    ai = od.get_variable(OD_ANALOG_INPUT_16, 1)
    assert ai.factor == WORD16_VOLTS_PER_LSB and ai.unit == "V" and "left-justified" in ai.description
    assert ai.decode_phys(16384) == pytest.approx(5.0)  # half scale, in volts (what Variable.phys reads)
    with pytest.raises(ValueError, match="not an EDS units file"):
        load_units(Path(__file__))
    assert json.loads(UNITS.read_text())["eds"] == EDS.name


def test_rww_outputs_state_where_they_refuse_writes_and_do_refuse_them() -> None:
    """0x6411 sub 1-2 are ``rww``: the EDS says (ObjFlags 0x1, comment lines and
    [Comments]) that SDO writes are refused outside OPERATIONAL with abort
    0x08000022, and the node does refuse them in PRE-OPERATIONAL and STOPPED."""
    cp = _eds()
    text = EDS.read_text()
    for sub in (1, 2):
        section = f"{OD_ANALOG_OUTPUT_16:04X}sub{sub}"
        assert cp[section]["AccessType"] == Access.RWW.value and cp[section]["ObjFlags"] == "0x1"
        body = text.split(f"[{section}]\n", 1)[1].split("\n\n", 1)[0]
        assert "0x08000022" in body and "OPERATIONAL" in body  # the comment line
    assert any("0x08000022" in v for k, v in cp["Comments"].items() if k.startswith("Line"))
    node = CanopenNode(FakeApp(), NodeConfig())
    write = struct.pack("<BHB", 0x2B, OD_ANALOG_OUTPUT_16, 1) + (160).to_bytes(2, "little") + b"\x00\x00"
    for state_frame in (None, encode_nmt(NmtCommand.STOP, 1)):
        if state_frame is not None:
            node.exchange(0x000, state_frame, 0.0)
            node.exchange(0x000, encode_nmt(NmtCommand.ENTER_PRE_OPERATIONAL, 1), 0.0)
        (reply,) = [f for f in node.exchange(0x601, write, 0.001) if f.arbitration_id == 0x581]
        assert reply.data[0] == 0x80 and struct.unpack_from("<I", reply.data, 4)[0] == SdoAbortCode.CANNOT_STORE_DEVICE_STATE
