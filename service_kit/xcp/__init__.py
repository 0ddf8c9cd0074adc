"""An XCP slave (ASAM MCD-1 XCP 1.x on Ethernet and on CAN) over a typed memory map.

:mod:`.packets` codes commands and responses, :mod:`.memory` lays out the
variables a table names, :mod:`.slave` is the protocol's state machine
(pure: no sockets, no clocks), :mod:`.partial` holds a parameter written in
parts (CAN), :mod:`.a2l` writes the ASAM MCD-2 MC file that describes the
same map, :mod:`.udp`, :mod:`.tcp` and :mod:`.can` serve it on a thread of
their own, :mod:`.transports` opens the ones a service's settings name
(docs/xcp.md).
"""
