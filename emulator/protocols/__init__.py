"""Printer-side wire protocols: one sans-IO state machine per wire format."""
