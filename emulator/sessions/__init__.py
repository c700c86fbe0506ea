"""Trio shells that join one protocol state machine to the printer model for one boot."""
