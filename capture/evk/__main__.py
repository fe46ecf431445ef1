from capture.evk.cli import main
raise SystemExit(main())
