"""Make this folder's helper modules (registration_scenes, registration_peers) importable when the
suite runs without the repository-level conftest that adds every test folder to sys.path."""

import sys
from pathlib import Path

_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.append(_HERE)
