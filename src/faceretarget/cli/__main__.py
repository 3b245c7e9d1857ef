"""``python -m faceretarget.cli ...``: the ``faceretarget`` command without the console script (an
environment that is not activated, a checkout on ``PYTHONPATH``)."""

import sys

from . import main

sys.exit(main())
