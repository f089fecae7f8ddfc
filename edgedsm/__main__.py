from edgedsm.cli import main

raise SystemExit(main())
