"""Test-wide settings: keep the synthetic world cache out of the user's home directory."""

import os
import tempfile
from pathlib import Path

# Shared by all test workers and runs (entries are keyed by code version and written atomically), so a
# repeated `make test` reuses rendered worlds instead of filling ~/.cache.
os.environ.setdefault("SOSMATCH_CACHE_DIR", str(Path(tempfile.gettempdir()) / "sosmatch-test-cache"))
