"""``python -m workbench.experiments`` was ``ralf-hil experiment``'s twin: it names it and exits 2."""

from service_kit.moved import exit_moved

exit_moved("python -m workbench.experiments", "ralf-hil experiment")
