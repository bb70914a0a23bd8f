import sys

from selfsense.cli import main

sys.exit(main())
