import sys

from evo_door.cli import main

sys.exit(main())
