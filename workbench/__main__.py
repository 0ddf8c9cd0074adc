"""``python -m workbench`` is ``ralf-hil`` (the console script's entry point
too): a Ctrl-C while the command's modules are still loading ends it with
one line and exit code 130, as one later does."""

from __future__ import annotations

import os
import signal
import sys

INTERRUPTED = 130
"""Exit code of a command ended by Ctrl-C (128 + SIGINT)."""


def _interrupted_while_loading(_signum: int, _frame: object) -> None:
    """Ctrl-C while the modules load: nothing has started yet, so nothing to stop."""
    os.write(2, b"ralf-hil: interrupted\n")
    os._exit(INTERRUPTED)


def main() -> int:
    # Ctrl-C is answered from the first line on, even where SIGINT came in
    # ignored (a background job of a non-interactive shell). While the modules
    # load it ends the process at once (a KeyboardInterrupt inside a compiled
    # extension's import can panic it); then it raises KeyboardInterrupt, and
    # up installs its own handler and stops the rig in order.
    signal.signal(signal.SIGINT, _interrupted_while_loading)
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
