"""``python -m hinfnn.cli`` runs the ``hinfnn`` command."""

import sys

from . import main

sys.exit(main())
