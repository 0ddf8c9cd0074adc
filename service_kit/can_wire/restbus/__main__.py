"""``python -m service_kit.can_wire.restbus``: :mod:`service_kit.can_wire.restbus.cli`."""

import sys

from service_kit.can_wire.restbus.cli import main

sys.exit(main())
