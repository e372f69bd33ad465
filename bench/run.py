"""Run the benchmark suite: ``python bench/run.py --out DIR [--quick]``.

The same as ``hydroarm bench --out DIR [--quick]`` and ``python -m hydroarm_bench``
(with ``bench/`` on ``PYTHONPATH``): the suite is the ``hydroarm_bench`` package next to
this file (see ``bench/README.md``). Running this file puts ``bench/`` on ``sys.path``.
"""

from __future__ import annotations

import sys

from hydroarm_bench.__main__ import main

if __name__ == "__main__":
    sys.exit(main())
