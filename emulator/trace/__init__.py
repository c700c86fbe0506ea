"""The wire trace (docs/trace.md)."""
