"""``python -m plant_emulator.canopen_node``: print the node's EDS."""

import sys

from plant_emulator.canopen_node.eds import render_eds

sys.stdout.write(render_eds())
