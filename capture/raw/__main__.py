"""``python -m capture.raw info FILE`` / ``python -m capture.raw convert FILE SESSION_DIR``."""

from capture.raw.cli import main

raise SystemExit(main())
