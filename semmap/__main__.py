from semmap.cli.main import main

raise SystemExit(main())
