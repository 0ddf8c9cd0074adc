"""The plant's compiled kernel in one place: :func:`warm_up` compiles (or
loads from numba's on-disk cache) the whole-period kernel (with the modal
step inside it), for images and CI to call once at install time so no
service spends its start-up compiling."""

from __future__ import annotations

from plant_emulator.model import _period_kernel


def warm_up() -> None:
    """Compile the whole-period kernel (it falls back to Python if numba cannot)."""
    _period_kernel.warm_up()
