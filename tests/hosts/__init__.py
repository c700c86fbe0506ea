"""Real printer host software (OctoPrint, Printrun's printcore) driven against the emulator.

Each host lives in its own virtual environment outside the checkout (see `venvs`), and the
drivers here run under that environment's interpreter, so they use only the standard library
besides the host package itself."""
