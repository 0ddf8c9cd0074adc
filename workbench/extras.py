"""The optional extras of ``pyproject.toml`` and the modules they install.

The quick start installs ``ralf-hil[rig]``; campaigns (Dask, Parquet, YAML
specs) and FMU plants need more. A command that reaches for a module its
install left out says which extra brings it, in one line, instead of a
traceback.
"""

from __future__ import annotations

EXTRAS = {"distributed": "campaign", "dask": "campaign", "pyarrow": "campaign", "yaml": "campaign", "fmpy": "fmu", "asammdf": "mf4", "hypothesis": "search"}
"""Top-level module -> the extra of pyproject.toml that installs it."""


def missing_extra(exc: BaseException) -> str | None:
    """``needs the module 'yaml': pip install 'ralf-hil[campaign]'`` for a
    ``ModuleNotFoundError`` of a module an extra installs; None for any other
    error (a module missing from the core install is a broken install, not a
    user's choice, and keeps its traceback)."""
    if not isinstance(exc, ModuleNotFoundError):
        return None
    extra = EXTRAS.get((exc.name or "").split(".")[0])
    if extra is None:
        return None
    return f"needs the module {exc.name!r}: pip install 'ralf-hil[{extra}]'"
