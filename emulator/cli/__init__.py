"""The command-line programs: `fake-marlin`, its `scenario` and `verify` commands."""
