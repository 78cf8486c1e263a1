"""``python -m catanc.runtime.worker``: run a worker (:func:`catanc.runtime.worker.process.main`)."""

import sys

from catanc.runtime.worker.process import main

sys.exit(main())
