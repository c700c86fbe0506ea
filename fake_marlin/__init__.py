"""fake-marlin: virtual 3D printers on pseudo-terminals, and a host client that streams G-code
to them.

The installed package holds three parts, kept in their own top-level folders of the source tree:
`fake_marlin.emulator` (the printer), `fake_marlin.host` (the host client) and `fake_marlin.wire`
(wire facts both share).
"""

__version__ = "0.4.0"
