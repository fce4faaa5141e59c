import sys

from jaxgfx.cli import main

sys.exit(main())
