"""Real printer host software (OctoPrint, Printrun's printcore, binproto2, cncjs) and the other
programs the tests drive (avrdude, Chromium, pyright), and the one step that installs them all:
`python -m tests.hosts.install` (install.py).

Each Python host lives in its own virtual environment outside the checkout (see `venvs`), and
the drivers here run under that environment's interpreter, so they use only the standard library
besides the host package itself."""
