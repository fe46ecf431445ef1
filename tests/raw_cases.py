"""The shared real recordings named in ``../shared/data/raw/expected.json`` (for parametrising tests)."""

import json

from tests.conftest import SHARED

EXPECTED_JSON = SHARED / "data" / "raw" / "expected.json"
EXPECTED = json.loads(EXPECTED_JSON.read_text())["files"] if EXPECTED_JSON.is_file() else {}
FILES = sorted(EXPECTED)
"""File names (empty when the shared data is missing: the fixture then skips)."""
FILES_WITH_NPY = sorted(n for n, e in EXPECTED.items() if e.get("reference_files"))
"""Files that come with an expelliarmus reference .npy."""
