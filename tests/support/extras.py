"""Run the estimator's command line as it runs without the 'train' extra."""

from __future__ import annotations

import subprocess
import sys

# A fresh interpreter where `import torch` finds nothing. (Not sys.modules["torch"] = None: libraries
# that look for torch there, as scipy does, would break where a real install without torch does not.)
_WITHOUT_TORCH = """
import sys

class NoTorch:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] == "torch":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)

sys.meta_path.insert(0, NoTorch())
from estimator.cli import main
sys.exit(main(sys.argv[1:]))
"""


def estimator_without_torch(*argv: str, timeout_s: float = 300) -> subprocess.CompletedProcess:
    """``estimator ARGV`` in a fresh interpreter that cannot import torch; output captured as text."""
    return subprocess.run([sys.executable, "-c", _WITHOUT_TORCH, *argv], capture_output=True, text=True,
                          timeout=timeout_s)
