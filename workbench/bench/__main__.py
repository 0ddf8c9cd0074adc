"""``python -m workbench.bench`` was ``ralf-hil bench``'s twin: it names it and exits 2."""

from service_kit.moved import exit_moved

exit_moved("python -m workbench.bench", "ralf-hil bench")
