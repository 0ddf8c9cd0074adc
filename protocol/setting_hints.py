"""The one answer to a misspelt setting, wherever it is given: ``ralf-hil up --set``,
a service's ``--set``, a ``RALF_*`` variable, the pytest fixture, a sweep spec.

:func:`unknown_setting` words it (one line: the closest names, or the service the
setting belongs to); :func:`refuse_misspelt_settings` checks a program's ``--set``
arguments and environment with it before the program loads its modules, so a
refusal takes the interpreter's start-up and no more. This module imports only the
standard library and :mod:`protocol.setting_names` (the names, generated from the
settings models), and creates nothing.
"""

from __future__ import annotations

import difflib
import os
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence

from protocol.setting_names import COMMON, RETIRED, SERVICES

ANY = "any"
"""A name meant for whichever service has it (``ralf-hil up --set seed=3``, a sweep axis)."""
COMMON_SERVICE = "common"
"""The settings every service has (the fixture's ``common`` table)."""
CLOSEST = 3
"""At most this many names are suggested."""


def names_of(service: str) -> tuple[str, ...]:
    """The settings of ``service`` (``plant``, ``controller``, ``dsp``, :data:`COMMON_SERVICE` or :data:`ANY`)."""
    if service == ANY:
        return tuple(dict.fromkeys(name for names in SERVICES.values() for name in names))
    if service == COMMON_SERVICE:
        return COMMON
    return SERVICES[service]


def normalized(name: str) -> str:
    """``RALF_OATF_MODE``, `` oatf_mode`` -> ``oatf_mode``."""
    return name.strip().lower().removeprefix("ralf_")


def variable(name: str) -> str:
    """A setting's environment variable: ``oatf_mode`` -> ``RALF_OATF_MODE``."""
    return f"RALF_{name.upper()}"


def _owners(name: str) -> list[str]:
    return [service for service, names in SERVICES.items() if name in names]


def _where(service: str) -> str:
    return "any service" if service == ANY else "every service" if service == COMMON_SERVICE else f"the {service}"


def _list(names: Sequence[str], conjunction: str = "or") -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + f" {conjunction} " + names[-1]


def unknown_setting(name: str, service: str = ANY, spell: Callable[[str], str] = repr) -> str | None:
    """None when ``name`` is a setting of ``service`` or a retired one (whose own reason is given
    elsewhere, :func:`protocol.settings.retired`); else the one line that says so, with the
    service it belongs to when it is another's, or the closest names. ``spell`` writes a name
    as the caller's user wrote it (quoted; :func:`variable` for the environment)."""
    name = normalized(name)
    known = names_of(service)
    if name in known or name in RETIRED:
        return None
    owners = _owners(name)
    if owners:
        return f"{spell(name)} is not a setting of {_where(service)}: it belongs to {_list([f'the {o}' for o in owners], 'and')}"
    close = difflib.get_close_matches(name, known, n=CLOSEST, cutoff=0.6)
    if close:
        return f"{spell(name)} is not a setting of {_where(service)}; did you mean {_list([spell(c) for c in close])}?"
    helps = "ralf-plant/ralf-controller/ralf-dsp" if service in (ANY, COMMON_SERVICE) else f"ralf-{service}"
    return f"{spell(name)} is not a setting of {_where(service)} (see {helps} --help for the settings)"


def unknown_variables(environ: Mapping[str, str]) -> list[str]:
    """The line for each ``RALF_*`` variable of ``environ`` that no program reads
    (checked against every program: ``ralf-hil up`` and compose give one environment to all three)."""
    out = []
    for var in sorted(environ):
        if var.upper().startswith("RALF_") and (line := unknown_setting(var, ANY, variable)) is not None:
            out.append(line)
    return out


def set_arguments(argv: Iterable[str]) -> list[str]:
    """The values of ``--set VALUE`` and ``--set=VALUE`` in ``argv`` (up to a ``--``)."""
    items: list[str] = []
    args = iter(argv)
    for arg in args:
        if arg == "--":
            break
        if arg == "--set":
            value = next(args, None)
            if value is not None:
                items.append(value)
        elif arg.startswith("--set="):
            items.append(arg.removeprefix("--set="))
    return items


def set_problem(item: str, service: str | None) -> str | None:
    """The line for one ``--set`` item that names no setting: ``NAME=VALUE`` given to ``service``,
    or (``service`` None: ``ralf-hil up``) ``[SERVICE.]NAME=VALUE``. None when the name is known,
    or when the item is malformed otherwise (its parser says how)."""
    target, sep, _ = item.partition("=")
    if not sep:
        return None
    if service is not None:
        line = unknown_setting(target, service)
    else:
        prefix, dot, name = target.rpartition(".")
        if dot and prefix not in SERVICES:
            return None
        line = unknown_setting(name, prefix if dot else ANY)
    return f"--set {item!r}: {line}" if line else None


def refuse_misspelt_settings(prog: str, service: str | None, argv: Sequence[str] | None = None, environ: Mapping[str, str] | None = None) -> None:
    """Before a program loads its modules: each ``--set`` of ``argv`` (default ``sys.argv[1:]``)
    and each ``RALF_*`` variable of ``environ`` that names no setting is written as one line,
    ``PROG: ...``, and the program exits with status 2."""
    args = sys.argv[1:] if argv is None else argv
    lines = [p for item in set_arguments(args) if (p := set_problem(item, service))]
    lines += unknown_variables(os.environ if environ is None else environ)
    if lines:
        for line in lines:
            print(f"{prog}: {line}", file=sys.stderr)
        raise SystemExit(2)
