import sys

from servo.cli import main

sys.exit(main())
