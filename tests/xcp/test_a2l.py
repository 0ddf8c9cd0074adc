"""The generated A2L, read back by pya2ldb (a parser nobody here wrote): every
measurement and calibration parameter of the table, at the address the slave
serves it, with its type, limits and conversion."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pya2l
import pya2l.model as model
import pytest
from pya2l.api.inspect import Measurement

from controller.xcp_table import A2L_MODULE, XCP_TABLE, controller_layout


def generate(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "controller.xcp_table", *args], capture_output=True, text=True, timeout=120, cwd=tmp_path, env={**os.environ})


def test_a2l_holds_the_table(tmp_path: Path) -> None:
    out = tmp_path / "ralf.a2l"
    done = generate(tmp_path, "-o", str(out), "--udp-port", "5555", "--tcp-port", "5556")
    assert done.returncode == 0, done.stderr
    session = pya2l.import_a2l(str(out), in_memory=True, progress_bar=False, loglevel="ERROR")
    (module,) = session.query(model.Module).all()
    assert module.name == A2L_MODULE
    layout = controller_layout()
    measurements = {m.name: m for m in session.query(model.Measurement)}
    characteristics = {c.name: c for c in session.query(model.Characteristic)}
    methods = {c.name: c for c in session.query(model.CompuMethod)}
    assert set(measurements) == {e.variable.name for e in XCP_TABLE if e.variable.kind == "measurement"}
    assert set(characteristics) == {e.variable.name for e in XCP_TABLE if e.variable.kind == "calibration"}
    for v in layout.variables:
        if v.kind == "measurement":
            m = measurements[v.name]
            assert (m.datatype, m.ecu_address.address) == (v.datatype, v.address), v.name
            assert (m.lowerLimit, m.upperLimit) == (v.lower, v.upper), v.name
            conversion = m.conversion
        else:
            c = characteristics[v.name]
            assert (c.type, c.address, c.deposit) == ("VALUE", v.address, f"RL_{v.datatype}"), v.name
            assert (c.lowerLimit, c.upperLimit) == (v.lower, v.upper), v.name
            conversion = c.conversion
        method = methods[conversion]
        assert method.conversionType == "LINEAR", v.name
        assert (method.coeffs_linear.a, method.coeffs_linear.b, method.unit) == (v.factor, v.offset, v.unit), v.name
    # pya2ldb's own conversion of a raw A/D word: 16384 LSB is half of the 10 V full scale
    assert Measurement(session, "ai1_word").compuMethod.int_to_physical(16384) == pytest.approx(5.0, rel=1e-12)
    text = out.read_text()
    assert "XCP_ON_UDP_IP 0x0104 5555" in text and "XCP_ON_TCP_IP 0x0104 5556" in text


def test_bad_arguments_one_line(tmp_path: Path) -> None:
    done = generate(tmp_path, "--udp-port", "70000")
    assert done.returncode == 2 and "Traceback" not in done.stderr and "invalid port_number value: '70000'" in done.stderr.splitlines()[-1]
    done = generate(tmp_path, "-o", str(tmp_path / "no" / "such" / "dir.a2l"))
    assert done.returncode == 1 and done.stderr.count("\n") == 1 and "cannot write" in done.stderr
