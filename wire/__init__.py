"""Wire primitives shared by the printer (emulator) and the host client."""
