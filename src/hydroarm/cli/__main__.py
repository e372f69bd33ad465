"""``python -m hydroarm.cli``."""

from hydroarm.cli import main

main()
