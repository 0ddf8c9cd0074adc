"""``python -m plant_emulator.canopen_node``: print the node's EDS; with
``--write DIR``, write the EDS and its units file into DIR instead
(``python -m plant_emulator.canopen_node --write protocol``)."""

import argparse
import sys
from pathlib import Path

from plant_emulator.canopen_node.eds import EDS_FILE_INFO, UNITS_FILE, render_eds, render_units

parser = argparse.ArgumentParser(prog="python -m plant_emulator.canopen_node", description="The plant node's CiA 306 EDS and its units file.")
parser.add_argument("--write", metavar="DIR", type=Path, help=f"write {EDS_FILE_INFO['FileName']} and {UNITS_FILE} into DIR")
args = parser.parse_args()
if args.write is None:
    sys.stdout.write(render_eds())
else:
    (args.write / EDS_FILE_INFO["FileName"]).write_text(render_eds())
    (args.write / UNITS_FILE).write_text(render_units())
