"""A run's record does not depend on the host's BLAS kernel.

OpenBLAS picks a kernel per CPU (``OPENBLAS_CORETYPE`` forces one), and its
kernels round matrix products differently in the last bit. Nothing on the
rig's state path calls BLAS or LAPACK at run time (the OATF's sum, the ETFE's
channel means and constants, the ARX's update are computed in defined
orders), so the same settings give the same record bit for bit whichever
kernel runs: checked by two co-simulations in processes with different
kernels (the ETFE and the ARX identifier, adaptive OATF). Before those
changes the records differed within 10 s.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

_RUN = """
import hashlib, sys
from workbench.cosim import run_cosim
for ident in ("etfe", "arx"):
    r = run_cosim({"duration_s": 20.0, "oatf_mode": "adaptive"}, dsp={"identifier": ident})
    cols = r.controller.record.to_columns()
    print(ident, r.result.ticks, hashlib.sha256(b"".join(cols[k].tobytes() for k in sorted(cols))).hexdigest())
"""


def _record_hashes(coretype: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if not k.startswith("OPENBLAS_")}
    if coretype is not None:
        env["OPENBLAS_CORETYPE"] = coretype
    out = subprocess.run([sys.executable, "-c", _RUN], env=env, capture_output=True, text=True, timeout=300, check=True)
    return out.stdout


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="OpenBLAS kernel names are the x86-64 ones")
def test_cosim_records_are_the_same_under_two_openblas_kernels() -> None:
    default = _record_hashes(None)  # the kernel OpenBLAS picks for this CPU
    nehalem = _record_hashes("Nehalem")  # SSE4.2: every x86-64 host that runs numpy 2 has it
    assert default.count("\n") == 2 and " 4000 " in default
    assert default == nehalem
