import sys

from vmehil.cli import main

sys.exit(main())
