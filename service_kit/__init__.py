"""The service kit: what each board's process stands on, below the boards and
above the contract (``protocol``). Process lifecycle (settings from the
command line, logging, SIGINT/SIGTERM, the zenoh session), the periodic
health message, latency statistics, and the clock/scheduler every board's
loop runs on (:mod:`service_kit.clock`). Nothing here imports a board or the
launcher (``workbench``)."""
