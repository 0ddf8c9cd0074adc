"""Property-based search for the smallest scenario that breaks the rig (docs/fault-search.md).

:mod:`~workbench.search.space` (what may vary), :mod:`~workbench.search.strategies`
(Hypothesis strategies over the rig's scenario formats),
:mod:`~workbench.search.properties` (what a run must hold; :mod:`~workbench.search.valves`
the valves-at-zero signals),
:mod:`~workbench.search.runner` (a candidate on :class:`workbench.hil.HilRig`),
:mod:`~workbench.search.engine` (the search, shrinking and confirmation),
:mod:`~workbench.search.bundle` (the failure bundle) and
:mod:`~workbench.search.cli` (``ralf-hil search``).
"""
