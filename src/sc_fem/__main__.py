from sc_fem._cli.main import main

raise SystemExit(main())
