"""Sans-IO codecs shared by the master and the simulator (bytes in, typed objects out).

- :mod:`.frame`: Ethernet/EtherCAT frame header, UDP encapsulation.
- :mod:`.datagram`: datagram commands, headers, working counters.
- :mod:`.registers`: the ESC register map (addresses, sizes, bits).
- :mod:`.al`: AL states and AL status codes.
- :mod:`.sii`: SII (EEPROM) image model and codec.
- :mod:`.mailbox`: mailbox header and the CoE, FoE, EoE and SoE protocols.
- :mod:`.pcap`: pcap/pcapng reading and writing.
"""

__all__: list[str] = []
