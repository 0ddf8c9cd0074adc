"""``python -m workbench`` is ``ralf-hil`` (the console script's entry point
too): a Ctrl-C while the command's modules are still loading ends it with
one line and exit code 130, as one later does."""

from __future__ import annotations

import os
import signal
import sys
from contextlib import nullcontext

from service_kit.interrupt import INTERRUPTED, end_at_once_on_ctrl_c


def main() -> int:
    # Ctrl-C is answered from the first line on, even where SIGINT came in
    # ignored (a background job of a non-interactive shell). While the modules
    # load it ends the process at once (a KeyboardInterrupt inside a compiled
    # extension's import can panic it); then it raises KeyboardInterrupt, and
    # up installs its own handler and stops the rig in order.
    end_at_once_on_ctrl_c("ralf-hil")
    from protocol.setting_hints import refuse_misspelt_settings  # after the handler: a Ctrl-C while they load is answered
    from workbench.progress import LONG_COMMANDS, activity, heartbeat_unless_terminal

    if sys.argv[1:2] == ["up"]:  # a misspelt setting is refused before the modules load
        refuse_misspelt_settings("ralf-hil up", None, sys.argv[2:])
    command = next((arg for arg in sys.argv[1:] if not arg.startswith("-")), "")
    # Without a terminal a long command's log hears from it from the start,
    # the loading of its modules included (seconds on a loaded host).
    with heartbeat_unless_terminal(f"ralf-hil {command}") if command in LONG_COMMANDS else nullcontext():
        with activity("loading the rig's modules"):
            from workbench.cli import main as cli_main

        signal.signal(signal.SIGINT, signal.default_int_handler)
        try:
            code = cli_main()
        except KeyboardInterrupt:
            print("ralf-hil: interrupted", file=sys.stderr)
            code = INTERRUPTED
    if code == INTERRUPTED:
        # Everything is stopped, closed and removed by now; the zenoh runtime's
        # own teardown at interpreter exit would add ~1 s to a Ctrl-C.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


if __name__ == "__main__":
    raise SystemExit(main())
