"""What the benchmark scripts share about their result files: the machine they ran on, the writing.

``machine()`` is the ``machine`` entry of a result (platform, Python, CPU count, numpy version and a
note that timings on the shared machine are noisy); ``write_result`` writes the result as indented
JSON, creating the folder.
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path
from typing import Any

import numpy as np


def machine() -> dict[str, Any]:
    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "numpy": np.__version__,
        "note": "shared 2-core machine, timings are noisy",
    }


def write_result(path: Path, result: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2))
