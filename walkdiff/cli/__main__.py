from walkdiff.cli.main import main

raise SystemExit(main())
