"""``python -m capture.raw info FILE``."""

from capture.raw.cli import main

raise SystemExit(main())
