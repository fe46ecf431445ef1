from capture.gopro.cli import main
raise SystemExit(main())
