from dynaslam2.cli import main

raise SystemExit(main())
