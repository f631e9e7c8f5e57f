"""``python -m ramps.cli ...`` is ``ramps ...`` (the tests and the testbed start nodes this way)."""

from ramps.cli import main

main()
