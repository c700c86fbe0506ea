"""Scenario files (TOML) and running one with the built-in host in simulated time."""
