"""``python -m kfusion``: the ``kfusion`` command (:func:`kfusion.cli.main`)."""

import sys

from kfusion.cli import main

sys.exit(main())
