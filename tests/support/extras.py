"""What runs without the 'train' extra: the estimator's command line, and the test modules."""

from __future__ import annotations

import subprocess
import sys

#: Test modules (relative to tests/) that import the train extra (torch) at their top: marked train and
#: not collected without torch (tests/conftest.py); test_check_selection.py keeps the list exact.
TRAIN_MODULES = frozenset({
    "estimator/inference/test_export_infer.py", "estimator/inference/test_hybrid.py",
    "estimator/training/test_export.py", "estimator/training/test_export_audit.py",
    "estimator/training/test_finetune.py", "estimator/training/test_finetune_audit.py",
    "estimator/training/test_finetune_cli_audit.py", "estimator/training/test_finetune_lineage.py",
    "estimator/training/test_model.py", "estimator/training/test_model_out.py",
    "estimator/training/test_model_write_errors.py", "estimator/training/test_pool.py",
    "estimator/training/test_pool_audit.py", "estimator/training/test_train.py",
    "estimator/training/test_train_audit.py",
})

# A fresh interpreter where `import torch` finds nothing. (Not sys.modules["torch"] = None: libraries
# that look for torch there, as scipy does, would break where a real install without torch does not.)
WITHOUT_TORCH = """
import sys

class NoTorch:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] == "torch":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)

sys.meta_path.insert(0, NoTorch())
"""


def estimator_without_torch(*argv: str, timeout_s: float = 300) -> subprocess.CompletedProcess:
    """``estimator ARGV`` in a fresh interpreter that cannot import torch; output captured as text."""
    script = WITHOUT_TORCH + "from estimator.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    return subprocess.run([sys.executable, "-c", script, *argv], capture_output=True, text=True,
                          timeout=timeout_s)
