import sys

from printability.cli.main import main

sys.exit(main())
