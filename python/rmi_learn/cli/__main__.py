"""``python -m rmi_learn.cli``: the ``rmi`` command without the console script."""

import sys

from rmi_learn.cli import main

sys.exit(main())
