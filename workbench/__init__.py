"""The workbench: everything a user runs the rig with, above the three boards.

``ralf-hil`` (:mod:`workbench.cli`): ``up`` and its one supervisor
(:mod:`workbench.launcher`), the one-process composition, the one-thread
co-simulation (:mod:`workbench.cosim`), the monitor, the benchmarks
(:mod:`workbench.bench`), the thesis's experiments (:mod:`workbench.experiments`),
recording, replay, plots and the file doctor (:mod:`workbench.recording`),
campaigns on Dask (:mod:`workbench.campaign`) and timing tests under scripted
link faults (:mod:`workbench.timing_test`). Nothing below it imports it; the
service image leaves it out.
"""
