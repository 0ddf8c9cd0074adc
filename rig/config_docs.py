"""The README's configuration tables, generated from the settings models so
they cannot drift (``python -m rig.config_docs`` prints them; a test checks
the README holds exactly this text)."""

from __future__ import annotations

from protocol.settings import CommonSettings, ControllerSettings, DspSettings, PlantSettings, describe

SECTIONS = (
    ("Common to all three", CommonSettings),
    ("Plant (`ralf-plant`)", PlantSettings),
    ("Controller (`ralf-controller`)", ControllerSettings),
    ("DSP (`ralf-dsp`)", DspSettings),
)


def config_tables() -> str:
    common = {row[0] for row in describe(CommonSettings)}
    parts = []
    for title, model in SECTIONS:
        rows = [r for r in describe(model) if model is CommonSettings or r[0] not in common]
        lines = [f"{title}:", "", "| variable | default | meaning |", "| --- | --- | --- |"]
        lines += [f"| `{var}` | `{default}` | {text.replace('|', '/')} |" for var, default, text in rows]
        parts.append("\n".join(lines))
    return "\n\n".join(parts)


if __name__ == "__main__":
    print(config_tables())
