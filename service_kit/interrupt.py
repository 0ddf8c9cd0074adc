"""Ctrl-C from a service's first line on.

A console script imports its module before it runs a line of it, and a
service's modules (numpy, numba, zenoh, its kernels) take a second or more
to load. Python's own SIGINT handler raises KeyboardInterrupt only when the
interpreter next runs Python code, and one raised inside a compiled
extension's import can panic it or be lost; a terminal's Ctrl-C in that
window left the service running on. :func:`end_at_once_on_ctrl_c`, called
first thing by each service's entry point, ends the process on SIGINT with
one line and exit code :data:`INTERRUPTED` until the service installs its
own handler (:func:`service_kit.runtime.stop_on_signals`), which stops it
in order. This module imports nothing but the standard library's ``os``,
``signal`` and ``sys`` (``logging`` only when :func:`end` runs), so the
handler is in place a few milliseconds after the interpreter has started;
a SIGINT before that, while the interpreter itself starts, gets Python's
own handling."""

from __future__ import annotations

import os
import signal
import sys

INTERRUPTED = 130
"""Exit code of a process ended by Ctrl-C (128 + SIGINT), as a shell reports it."""


def end_at_once_on_ctrl_c(prog: str) -> None:
    """Until replaced, SIGINT writes ``PROG: interrupted`` to stderr and ends
    the process with :data:`INTERRUPTED`; nothing has started yet, so there is
    nothing to stop or close. Also where SIGINT came in ignored (a background
    job of a non-interactive shell): a service answers Ctrl-C wherever it runs."""
    line = f"{prog}: interrupted\n".encode()

    def _interrupted_while_loading(_signum: int, _frame: object) -> None:
        os.write(2, line)
        os._exit(INTERRUPTED)

    signal.signal(signal.SIGINT, _interrupted_while_loading)


def end(code: int) -> int:
    """A service's way out: ``code``, except that a run ended by Ctrl-C
    (:data:`INTERRUPTED`; everything is stopped, closed and removed by then)
    ends the process at once, logs flushed: the interpreter's own teardown of
    the zenoh runtime and numba would add up to a second to a Ctrl-C."""
    if code == INTERRUPTED:
        import logging  # loaded by every service long before; not at this module's import (it would delay the handler)

        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code
