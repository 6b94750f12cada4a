import sys

from physdyn.cli import main

sys.exit(main())
