"""Thin trio clients, one per protocol, on the shared shell (fake_marlin.host.shell)."""
