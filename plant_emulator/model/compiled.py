"""The plant's compiled kernels in one place: :func:`warm_up` compiles (or
loads from numba's on-disk cache) every one of them, for images and CI to
call once at install time so no service spends its start-up compiling."""

from __future__ import annotations

from plant_emulator.model import _modal_kernel, _period_kernel


def warm_up() -> None:
    """Compile the modal step and the whole-period kernel (each falls back to Python if numba cannot)."""
    _modal_kernel.warm_up()
    _period_kernel.warm_up()
