import sys

from printability.app.cli.main import main

sys.exit(main())
