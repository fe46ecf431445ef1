from capture.review.cli import main

raise SystemExit(main())
