import sys

from pointillist.cli import main

sys.exit(main())
