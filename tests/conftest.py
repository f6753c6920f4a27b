"""Shared helpers for the pytest suite (runs against the installed package)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT.parent / "shared" / "scenes"
if not SCENES.is_dir():
    SCENES = ROOT / "examples" / "scenes"


def run_gammac(*args, cwd=None, timeout=600):
    """Run the CLI as a user would; returns the CompletedProcess."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.run([sys.executable, "-m", "gamma.cli", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout, env=env)


@pytest.fixture(scope="session")
def rt():
    import gamma._runtime as runtime

    return runtime
