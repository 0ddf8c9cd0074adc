"""Moved to :mod:`service_kit.runtime` (the boards must not import the launcher);
kept as an alias for callers in the launcher, bench and experiments."""

from service_kit.runtime import *  # noqa: F401,F403
from service_kit.runtime import HealthPublisher, LatencyTracker, build_or_config_error, run_service, wall_time  # noqa: F401
