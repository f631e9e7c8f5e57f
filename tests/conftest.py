import sys
from pathlib import Path

# let test modules share helpers (tests/corehelpers.py) without a package
sys.path.insert(0, str(Path(__file__).parent))
