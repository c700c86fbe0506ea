import sys

from fake_marlin.emulator.cli.main import main

sys.exit(main())
