"""The control channel: JSON lines on a Unix socket, served by the printer, and its client."""
